"""What the browser tests share: the App on a real-time SimClock, Debian's Chromium driven by
Playwright on a desktop (1280×800) or a phone (390×844) viewport, and helpers that wait for
conditions (never for a fixed time) and save screenshots to ``artifacts/screenshots/``.

Playwright drives ``/usr/bin/chromium`` (never ``playwright install``).
"""

from __future__ import annotations

import asyncio
import contextlib
import shutil
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from playwright import async_api as playwright_api

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.topics import GROUND_TRUTH
from curio.web.tokens import TokenStore

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run",
                 "--autoplay-policy=no-user-gesture-required"]
SHOTS = REPO_ROOT / "artifacts" / "screenshots"
SPEED = 4.0  # simulated seconds per wall second
# Teleop runs slower: the page sends every 0.1 s of wall time and the deadman is 0.5 s of
# simulated time, so the simulation must not run more than ~3× faster than the wall clock.
TELEOP_SPEED = 2.0
VIEWPORTS: dict[str, dict[str, Any]] = {
    "desktop": {"viewport": {"width": 1280, "height": 800}},
    "phone": {"viewport": {"width": 390, "height": 844}, "device_scale_factor": 2,
              "is_mobile": True, "has_touch": True},
}

if shutil.which(CHROMIUM) is None:  # pragma: no cover - the README's test command installs it
    pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium", pytrace=False)


def make_cfg(data_dir: Path, *extra: str) -> Config:
    return load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{data_dir}"', "web.enabled=true", "web.port=0", "bt.speak=false",
        *extra])


def add_token(cfg: Config, name: str, role: str = "operator") -> str:
    """Make a named token in the config's data dir (what ``curio token create`` does)."""
    store = TokenStore(cfg.data_path(cfg.web.tokens_file), cfg.data_path(cfg.web.token_file))
    store.ensure_admin()
    return store.create(name, role).token


@contextlib.asynccontextmanager
async def running_app(cfg: Config, speed: float = SPEED, epoch_wall_s: float = 1_700_000_000.0
                      ) -> AsyncIterator[tuple[App, SimClock]]:
    clock = SimClock(speed=speed, epoch_wall_s=epoch_wall_s)
    app = App(cfg, clock, web=True)
    await app.start()
    runner = asyncio.create_task(clock.run(), name="sim-clock")
    try:
        yield app, clock
        assert app.failed_parts() == []
    finally:
        await app.stop()
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner


class Browser:
    """A page on one viewport plus every console error and uncaught exception it produced."""

    def __init__(self, page: Any, viewport: str) -> None:
        self.page = page
        self.viewport = viewport
        self.errors: list[str] = []
        page.on("console", lambda m: self.errors.append(f"console.{m.type}: {m.text}")
                if m.type == "error" and not self.expected(m.text) else None)
        page.on("pageerror", lambda e: self.errors.append(f"pageerror: {e}"))
        self.allowed: list[str] = []

    def expected(self, text: str) -> bool:
        return any(a in text for a in self.allowed)

    async def shot(self, name: str, selector: str | None = None) -> Path:
        """Save ``<viewport>-<name>.png``: what the operator sees, with the element
        ``selector`` (a panel) scrolled to just under the sticky STOP and status."""
        SHOTS.mkdir(parents=True, exist_ok=True)
        path = SHOTS / f"{self.viewport}-{name}.png"
        if selector is not None:
            # window.scrollTo moves the page only (scrollIntoView near the end of a page on a
            # phone also pans the visual viewport, which cut the sticky header off the shot).
            await self.page.evaluate("""(sel) => {
                const el = document.querySelector(sel);
                const sticky = document.querySelector('#sticky, #top');
                const top = sticky ? sticky.getBoundingClientRect().height : 0;
                window.scrollTo(0, el.getBoundingClientRect().top + window.scrollY - top - 4);
            }""", selector)
        await self.page.screenshot(path=str(path))
        return path

    async def state(self, expr: str) -> Any:
        return await self.page.evaluate(f"() => {expr}")

    async def wait_js(self, expr: str, timeout_s: float = 20.0) -> None:
        await self.page.wait_for_function(f"() => {expr}", timeout=timeout_s * 1000)

    async def text(self, selector: str) -> str:
        return (await self.page.text_content(selector)) or ""

    async def map_point(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Where map point (x_m, y_m) is on the page, CSS pixels (the map scrolled into view:
        on a phone it is at the top of the page)."""
        if not await self.in_view("#map"):
            await self.page.evaluate("() => window.scrollTo(0, 0)")
        box = await self.page.locator("#map").bounding_box()
        sx, sy = await self.page.evaluate(f"() => window.curio.toScreen({x_m}, {y_m})")
        return box["x"] + sx, box["y"] + sy

    async def click_map(self, x_m: float, y_m: float, drag_to: tuple[float, float] | None = None
                        ) -> None:
        """Press on the map at map point (x_m, y_m) with the real mouse (drag: to the other)."""
        mouse = self.page.mouse
        await mouse.move(*await self.map_point(x_m, y_m))
        await mouse.down()
        if drag_to is not None:
            await mouse.move(*await self.map_point(*drag_to), steps=5)
        await mouse.up()

    async def look_at(self, x_m: float, y_m: float, min_px_per_m: float) -> None:
        """Centre the map on (x_m, y_m) at least this zoomed in, as an operator would (the
        rover is no longer followed)."""
        await self.page.evaluate(f"""() => {{
            document.getElementById('follow').checked = false;
            const v = window.curio.view; v.cx = {x_m}; v.cy = {y_m};
            v.scale = Math.max(v.scale, {min_px_per_m}); v.dirty = true; }}""")

    async def in_view(self, selector: str) -> bool:
        """Whether the element is inside the viewport and not covered by another one."""
        return bool(await self.page.evaluate("""(sel) => {
            const el = document.querySelector(sel), r = el.getBoundingClientRect();
            if (r.width === 0 || r.top < 0 || r.bottom > innerHeight || r.left < 0 ||
                r.right > innerWidth) return false;
            const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
            return hit === el || el.contains(hit);
        }""", selector))

    async def confirm(self, expected: str, accept: bool) -> None:
        """Answer the page's confirm box (after checking what it asks)."""
        await self.wait_js("!document.querySelector('#modal').classList.contains('hidden')")
        assert expected in await self.text("#modalText")
        await self.page.click("#modalOk" if accept else "#modalCancel")


@contextlib.asynccontextmanager
async def chromium() -> AsyncIterator[Any]:
    async with playwright_api.async_playwright() as p:
        browser = await p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            await browser.close()


async def open_page(browser: Any, url: str, viewport: str, connected: bool = True) -> Browser:
    """A new browser context (its own storage: one operator) with the page at ``url``."""
    context = await browser.new_context(**VIEWPORTS[viewport])
    page = await context.new_page()
    b = Browser(page, viewport)
    await page.goto(url)
    if connected:
        await b.wait_js("window.curio && window.curio.S.connected && window.curio.S.status")
    return b


@contextlib.asynccontextmanager
async def browser_on(url: str, viewport: str) -> AsyncIterator[Browser]:
    async with chromium() as browser:
        yield await open_page(browser, url, viewport)


def truth_xy(app: App) -> tuple[float, float]:
    gt = app.bus.latest(GROUND_TRUTH)
    assert gt is not None, "the simulator publishes no ground truth"
    return gt.pose.x, gt.pose.y
