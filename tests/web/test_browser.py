"""End-to-end: the whole App on a real-time SimClock, driven through a real headless Chromium.

Playwright drives Debian's ``/usr/bin/chromium`` (never ``playwright install``). Screenshots
go to ``artifacts/screenshots/`` (gitignored). These tests need the simulator, estimation,
navigation and the behaviour tree; each one says which parts it drives.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import shutil
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from playwright import async_api as playwright_api

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.topics import CMD_VEL, GROUND_TRUTH, INITIAL_POSE, OPERATOR

pytestmark = [pytest.mark.browser]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
SHOTS = REPO_ROOT / "artifacts" / "screenshots"
SPEED = 4.0  # simulated seconds per wall second
# Teleop runs slower: the page sends every 0.1 s of wall time and the deadman is 0.5 s of
# simulated time, so the simulation must not run more than ~3× faster than the wall clock.
TELEOP_SPEED = 2.0

if shutil.which(CHROMIUM) is None:  # pragma: no cover - the README's test command installs it
    pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium", pytrace=False)


def make_cfg(data_dir: Path, *extra: str) -> Config:
    return load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{data_dir}"', "web.enabled=true", "web.port=0", "bt.speak=false",
        *extra])


@contextlib.asynccontextmanager
async def running_app(cfg: Config, speed: float = SPEED
                      ) -> AsyncIterator[tuple[App, SimClock]]:
    clock = SimClock(speed=speed)
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
    """A page plus every console error and uncaught exception it produced."""

    def __init__(self, page: Any) -> None:
        self.page = page
        self.errors: list[str] = []
        page.on("console", lambda m: self.errors.append(f"console.{m.type}: {m.text}")
                if m.type == "error" else None)
        page.on("pageerror", lambda e: self.errors.append(f"pageerror: {e}"))

    async def shot(self, name: str) -> Path:
        SHOTS.mkdir(parents=True, exist_ok=True)
        path = SHOTS / f"{name}.png"
        await self.page.screenshot(path=str(path))
        return path

    async def state(self, expr: str) -> Any:
        return await self.page.evaluate(f"() => {expr}")

    async def wait_js(self, expr: str, timeout_s: float = 20.0) -> None:
        await self.page.wait_for_function(f"() => {expr}", timeout=timeout_s * 1000)

    async def click_map(self, x_m: float, y_m: float, drag_to: tuple[float, float] | None = None
                        ) -> None:
        """Click the map canvas at map point (x_m, y_m) with the real mouse."""
        box = await self.page.locator("#map").bounding_box()
        sx, sy = await self.page.evaluate(f"() => window.curio.toScreen({x_m}, {y_m})")
        mouse = self.page.mouse
        await mouse.move(box["x"] + sx, box["y"] + sy)
        await mouse.down()
        if drag_to is not None:
            tx, ty = await self.page.evaluate(
                f"() => window.curio.toScreen({drag_to[0]}, {drag_to[1]})")
            await mouse.move(box["x"] + tx, box["y"] + ty, steps=5)
        await mouse.up()


@contextlib.asynccontextmanager
async def browser_on(url: str) -> AsyncIterator[Browser]:
    async with playwright_api.async_playwright() as p:
        chromium = await p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = await chromium.new_page(viewport={"width": 1400, "height": 900})
            b = Browser(page)
            await page.goto(url)
            await b.wait_js("window.curio && window.curio.S.connected && window.curio.S.status")
            yield b
        finally:
            await chromium.close()


def truth_xy(app: App) -> tuple[float, float]:
    gt = app.bus.latest(GROUND_TRUTH)
    assert gt is not None, "the simulator publishes no ground truth"
    return gt.pose.x, gt.pose.y


async def test_operator_controls_drive_the_rover(tmp_path: Path) -> None:
    """Page loads cleanly; a goal clicked on the map moves the rover; Pause/Resume; Go Home;
    a bad path number shows an error. Drives: sim, estimation, navigation, behaviour tree."""
    async with running_app(make_cfg(tmp_path / "data")) as (app, clock):
        assert app.web_url is not None and "token=" in app.web_url
        async with browser_on(app.web_url) as b:
            page = b.page
            assert await page.text_content("#mode") == "You can control"
            await b.wait_js("window.curio.S.images.map && window.curio.S.pose")
            await b.shot("01-loaded")
            # The costmap overlay is fetched (as a PNG) only when it is switched on.
            assert await b.state("!window.curio.S.images.costmap")
            await page.check("#showCostmap")
            await b.wait_js("!!window.curio.S.images.costmap")
            await page.uncheck("#showCostmap")

            # A bad path number: a visible, specific message, nothing sent.
            await page.fill("#pathInput", "7")
            await page.press("#pathInput", "Enter")
            await b.wait_js("document.querySelector('#pathMsg').textContent.includes('no path 7')")
            assert "paths are 0–2" in (await page.text_content("#pathMsg") or "")
            assert "error" in (await page.get_attribute("#pathMsg", "class") or "")
            await page.fill("#pathInput", "two")
            await page.click("#pathEnter")
            await b.wait_js("document.querySelector('#pathMsg').textContent.includes('not a path')")
            await b.shot("02-bad-path-number")

            # Send the rover to a point by clicking the map.
            start = truth_xy(app)
            await page.click("[data-tool=goal]")
            await b.click_map(start[0] + 2.0, start[1])
            await b.wait_js("window.curio.S.status.state === 'moving'")
            await b.wait_js(f"window.curio.S.pose && Math.hypot(window.curio.S.pose.x - {start[0]},"
                            f" window.curio.S.pose.y - {start[1]}) > 0.3", timeout_s=30)
            await b.shot("03-moving")

            # Pause: the button and the badge follow the rover's real state.
            await page.click("#pause")
            await b.wait_js("window.curio.S.status.state === 'paused'")
            await b.wait_js("document.querySelector('#pause').textContent.includes('Resume')")
            assert await page.text_content("#stateBadge") == "Paused"
            await clock.sleep(1.0)
            x0 = truth_xy(app)
            await clock.sleep(1.0)
            assert math.dist(x0, truth_xy(app)) < 0.05, "the rover kept moving while paused"
            await b.shot("04-paused")
            await page.click("#pause")
            await b.wait_js("window.curio.S.status.state !== 'paused'")
            await b.wait_js("document.querySelector('#pause').textContent.includes('Pause')")

            # Go Home sends it home.
            await page.click("#goHome")
            await b.wait_js("window.curio.S.status.state === 'going_home'")
            await b.shot("05-going-home")
            home = app.cfg.robot.home
            assert await clock.wait_until(
                lambda: math.dist(truth_xy(app), home[:2]) < 0.35, timeout_s=90.0), \
                f"not home: {truth_xy(app)}"
            await b.wait_js("window.curio.S.status.state === 'arrived'", timeout_s=30)
            await b.shot("06-home")
            assert b.errors == []


async def test_clicked_waypoints_survive_a_restart(tmp_path: Path) -> None:
    """Path editor: a new path and two clicked waypoints persist; the pose tool publishes an
    initial pose. Drives: behaviour tree (path manager), simulator (map)."""
    data = tmp_path / "data"
    async with running_app(make_cfg(data)) as (app, clock), browser_on(app.web_url or "") as b:
        page = b.page
        await b.wait_js("window.curio.S.images.map")
        await page.click("#pathsCard summary")
        await page.click("#newPath")
        await b.wait_js("window.curio.S.editPathId !== null")
        new_id = await b.state("window.curio.S.editPathId")
        assert await b.state("document.querySelector('.tool.active').dataset.tool") \
                == "waypoint"
        await b.click_map(1.0, 0.5)
        await b.wait_js(f"window.curio.S.paths.find(p => p.id === {new_id})"
                        ".waypoints.length === 1")
        await b.click_map(2.0, 1.0, drag_to=(2.0, 2.0))  # drag: the waypoint faces +y
        await b.wait_js(f"window.curio.S.paths.find(p => p.id === {new_id})"
                        ".waypoints.length === 2")
        # Zoom with the wheel and with a two-finger pinch (touch pointers).
        await page.click("[data-tool=look]")
        scale0 = await b.state("window.curio.view.scale")
        box = await page.locator("#map").bounding_box()
        await page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        await page.mouse.wheel(0, -300)
        await b.wait_js(f"window.curio.view.scale > {scale0} * 1.3")
        scale1 = await b.state("window.curio.view.scale")
        await page.evaluate("""() => {
            const c = document.getElementById('map'), r = c.getBoundingClientRect();
            const cx = r.left + r.width / 2, cy = r.top + r.height / 2;
            const ev = (type, id, dx) => c.dispatchEvent(new PointerEvent(type, {
                pointerId: id, pointerType: 'touch', clientX: cx + dx, clientY: cy,
                bubbles: true, isPrimary: id === 1}));
            ev('pointerdown', 1, -20); ev('pointerdown', 2, 20);
            for (let k = 1; k <= 5; k++) { ev('pointermove', 1, -20 - 10 * k);
                                           ev('pointermove', 2, 20 + 10 * k); }
            ev('pointerup', 1, -70); ev('pointerup', 2, 70);
        }""")
        assert await b.state("window.curio.view.scale") == pytest.approx(scale1 * 70 / 20,
                                                                          rel=0.01)
        await page.click("#fit")

        # Drag with the pose tool: an initial pose in map, facing the drag direction.
        poses = app.bus.subscribe(INITIAL_POSE)
        await page.click("[data-tool=pose]")
        await b.click_map(0.0, 0.0, drag_to=(-1.0, 0.0))
        assert await clock.wait_until(lambda: len(poses) > 0, timeout_s=10.0)
        (initial,) = poses.drain()
        assert (initial.pose.x, initial.pose.y) == pytest.approx((0.0, 0.0), abs=0.05)
        assert abs(abs(initial.pose.yaw) - math.pi) < 0.05
        await page.fill("#pathName", "Lab visit")
        await page.click("#renamePath")
        await b.wait_js(f"window.curio.S.paths.find(p => p.id === {new_id}).name === "
                        "'Lab visit'")
        await b.shot("07-path-editor")

        # The live link drops: the page says so, reconnects by itself, catches up on the
        # state, and sends nothing on its own.
        ops = app.bus.subscribe(OPERATOR)
        await b.state("window.curio.S.ws.close()")
        await b.wait_js("document.querySelector('#conn').textContent === 'Reconnecting…'")
        await b.wait_js("window.curio.S.connected && window.curio.S.status !== null")
        assert await b.page.text_content("#conn") == "Connected"
        await clock.sleep(1.0)
        assert ops.drain() == []
        assert b.errors == []

    async with running_app(make_cfg(data)) as (app, _clock):
        saved = app.paths.get(new_id)
        assert saved.name == "Lab visit"
        assert [(round(w.x_m, 1), round(w.y_m, 1)) for w in saved.waypoints] == \
            [(1.0, 0.5), (2.0, 1.0)]
        assert saved.waypoints[0].yaw_rad is None
        assert saved.waypoints[1].yaw_rad == pytest.approx(math.pi / 2, abs=0.05)
        async with browser_on(app.web_url or "") as b:
            text = await b.page.text_content("#pathList")
            assert f"{new_id}: Lab visit" in (text or "")


async def test_blocked_door_shows_help_me_then_thanks(tmp_path: Path) -> None:
    """The library door closes in front of the rover driving a path typed by number: HELP ME
    blinks; the door reopens: Thanks!. Drives: sim world (doors), navigation (blocked
    detector), behaviour tree (path follower, Ask4Help).

    The recovery ladder is cut to ``wait`` and the no-progress time to 2 s so that the help
    request comes before the navigator gives the goal up (with the default ladder the
    navigator's own recoveries reverse away from the door and the goal is aborted instead).
    """
    cfg = make_cfg(tmp_path / "data", "sim.start=[1.55, 7.9, 1.5708]",
                   "nav.blocked.no_progress_s=2", 'nav.recovery.ladder=["wait"]',
                   "nav.recovery.wait_s=10")
    async with running_app(cfg) as (app, clock), browser_on(app.web_url or "") as b:
        pid = app.paths.create("Library").id
        app.paths.add_waypoint(pid, 1.2, 11.5)
        page = b.page
        await b.wait_js("window.curio.S.images.map && window.curio.S.pose")
        await b.wait_js(f"window.curio.S.paths.some(p => p.id === {pid})")
        await page.fill("#pathInput", str(pid))
        await page.press("#pathInput", "Enter")
        await b.wait_js("window.curio.S.status.state === 'moving'")
        assert await clock.wait_until(lambda: truth_xy(app)[1] > 8.1, timeout_s=20.0)
        app.world.set_door("library", False)
        await b.wait_js("document.querySelector('#help').textContent === 'HELP ME!'",
                        timeout_s=60)
        assert "active" in (await page.get_attribute("#help", "class") or "")
        assert await page.is_visible("#helpDone")
        assert await page.text_content("#stateBadge") == "Needs help"
        await b.shot("08-help-me")
        app.world.set_door("library", True)
        await b.wait_js("document.querySelector('#help').textContent === 'Thanks!'",
                        timeout_s=60)
        await b.shot("09-thanks")
        assert b.errors == []


async def test_teleop_moves_and_release_stops(tmp_path: Path) -> None:
    """Hold the joystick forward: the rover drives; let go: it stops; the e-stop latches and
    releases; the arrow keys drive with the same deadman. Drives: sim, safety stage."""
    async with running_app(make_cfg(tmp_path / "data"), TELEOP_SPEED) as (app, clock), \
            browser_on(app.web_url or "") as b:
        page = b.page
        await b.wait_js("window.curio.S.pose")
        start = truth_xy(app)
        joy = await page.locator("#joystick").bounding_box()
        cx, cy = joy["x"] + joy["width"] / 2, joy["y"] + joy["height"] / 2
        await page.mouse.move(cx, cy)
        await page.mouse.down()
        await page.mouse.move(cx, cy - joy["height"] * 0.4, steps=4)
        assert await clock.wait_until(
            lambda: math.dist(start, truth_xy(app)) > 0.15, timeout_s=10.0), \
            "the rover did not move under teleop"
        await b.shot("10-teleop")
        await page.mouse.up()
        await clock.sleep(1.0)  # deadman: stopped within the safety timeout and ramp
        cmd = app.bus.latest(CMD_VEL)
        assert cmd is not None and abs(cmd.linear_mps) < 1e-3
        held = truth_xy(app)
        await clock.sleep(1.0)
        assert math.dist(held, truth_xy(app)) < 0.02, "the rover kept moving after release"

        # The always-visible e-stop latches; teleop cannot move the rover until released.
        await page.click("#estop")
        await b.wait_js("window.curio.S.estop && window.curio.S.estop.engaged")
        assert await page.is_visible("#estopBanner")
        assert await page.text_content("#stateBadge") == "E-STOP"
        await b.shot("11-estop")
        held = truth_xy(app)
        await page.mouse.move(cx, cy)
        await page.mouse.down()
        await page.mouse.move(cx, cy - joy["height"] * 0.4, steps=4)
        await clock.sleep(1.5)
        await page.mouse.up()
        assert math.dist(held, truth_xy(app)) < 0.02, "the rover moved during an e-stop"
        await page.click("#releaseEstop")
        await b.wait_js("window.curio.S.estop && !window.curio.S.estop.engaged")
        assert not await page.is_visible("#estopBanner")

        # The keyboard drives too (arrow keys), with the same deadman.
        start = truth_xy(app)
        await page.keyboard.down("ArrowUp")
        assert await clock.wait_until(
            lambda: math.dist(start, truth_xy(app)) > 0.15, timeout_s=10.0), \
            "the rover did not move with the arrow key held"
        await page.keyboard.up("ArrowUp")
        await clock.sleep(1.0)
        held = truth_xy(app)
        await clock.sleep(1.0)
        assert math.dist(held, truth_xy(app)) < 0.02, "the rover kept moving after the key"
        assert b.errors == []


async def test_tour_start_and_stop_buttons(tmp_path: Path) -> None:
    """With the tour tree: Start tour starts it, Stop this trip ends it, both from the tree's
    state. Drives: behaviour tree (tour), navigation, sim."""
    cfg = make_cfg(tmp_path / "data", 'bt.tree="tour"',
                   'bt.tour_stops=[{name="Lobby", x_m=2.0, y_m=-2.5, dwell_s=1.0, '
                   'message="Welcome"}]')
    async with running_app(cfg) as (app, _clock), browser_on(app.web_url or "") as b:
        page = b.page
        assert await page.is_visible("#startTour")
        assert not await page.is_visible("#cancelTrip")
        await page.click("#startTour")
        await b.wait_js("['tour', 'moving'].includes(window.curio.S.status.state)")
        await b.wait_js("document.querySelector('#cmdMsg').textContent.includes('Tour started')")
        await b.wait_js("!document.querySelector('#cancelTrip').classList.contains('hidden')")
        await b.shot("12-tour")
        await page.click("#cancelTrip")
        await b.wait_js("window.curio.S.status.state === 'idle'")
        assert not await page.is_visible("#cancelTrip")
        assert b.errors == []
