"""End-to-end (the whole App on a real-time SimClock, Debian's Chromium on a desktop and a phone):
a tour authored on the map (click, drag for the heading, a stop in a wall refused, drag to
move, reorder, edit, duplicate, delete), scheduled in the building's time zone (an overlap
refused with the reason) and started by the scheduler at its time on the simulated clock; the
visitors' kiosk starting a tour and following it (and a tablet in portrait and landscape).
Screenshots in ``artifacts/screenshots/``. Every wait is for a condition.
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import pytest

from curio.app import App
from curio.core.topics import EVENTS, OPERATOR
from tests.web.browser_kit import (
    VIEWPORTS,
    Browser,
    add_token,
    browser_on,
    chromium,
    make_cfg,
    open_page,
    running_app,
)

pytestmark = [pytest.mark.browser]

LONDON = ZoneInfo("Europe/London")
# Monday 2 June 2025, 09:50 in London: the building's clock when the App starts.
MONDAY_0950 = dt.datetime(2025, 6, 2, 9, 50, tzinfo=LONDON).timestamp()
TOURS = "window.curio.tours"
STOPS = f"{TOURS}.list.find(t => t.id === {TOURS}.selId).stops"


def wall_point(app: App, near: tuple[float, float]) -> tuple[float, float]:
    """The middle of a solid obstacle of the map (7×7 cells occupied) nearest to ``near``."""
    grid = app.map_server.grid
    occ = grid.occupied_mask()
    best: tuple[float, float, float] | None = None
    for r, c in zip(*np.nonzero(occ), strict=True):
        if occ[max(0, r - 3):r + 4, max(0, c - 3):c + 4].all():
            x, y = grid.cell_to_world(int(r), int(c))
            d = math.dist((x, y), near)
            if best is None or d < best[0]:
                best = (d, x, y)
    assert best is not None and app.tours.placement(best[1], best[2]) is not None
    return best[1], best[2]


async def drag_stop(b: Browser, frm: tuple[float, float], to: tuple[float, float]) -> None:
    await b.click_map(*frm, drag_to=to)


async def add_stop(b: Browser, at: tuple[float, float], name: str, n: int,
                   face: tuple[float, float] | None = None, message: str = "") -> None:
    """Click (or drag for the heading) on the map, name the stop, Add: the tour has ``n``."""
    await b.click_map(*at, drag_to=face)
    await b.wait_js("!document.querySelector('#stopSave').disabled")
    await b.page.fill("#stopName", name)
    await b.page.fill("#stopDwell", "3")
    if message:
        await b.page.fill("#stopText", message)
    await b.page.click("#stopSave")
    await b.wait_js(f"{STOPS}.length === {n}")


async def test_author_a_tour_on_the_map_and_schedule_it(tmp_path: Path, viewport: str) -> None:
    """Tours and Schedule cards with an operator token. Drives: tours (stores, placement,
    scheduler), the behaviour tree (tour), navigation, sim."""
    cfg = make_cfg(tmp_path / "data", 'bt.tree="tour"', 'tours.timezone="Europe/London"')
    token = add_token(cfg, "alice")
    async with running_app(cfg, epoch_wall_s=MONDAY_0950) as (app, clock):
        url = (app.web_url or "").split("?")[0] + f"?token={token}"
        async with browser_on(url, viewport) as b:
            page = b.page
            await b.wait_js(f"window.curio.S.images.map && {TOURS}.loaded")
            await page.click("#toursCard summary")
            await page.click("#tourNew")
            await b.wait_js(f"{TOURS}.list.length === 2 && {STOPS}.length === 0")
            assert await b.state("window.curio.tool") == "stops"
            await page.fill("#tourName", "Garden walk")
            await page.click("#tourRename")
            await b.wait_js(f"{TOURS}.list.some(t => t.name === 'Garden walk')")
            await b.look_at(4.0, -1.0, 40.0)

            # Click to add; drag for the heading; a stop in a wall is refused with the reason.
            await add_stop(b, (2.0, -2.0), "Desk", 1, message="Welcome to the garden walk!")
            await add_stop(b, (3.0, 1.0), "Window", 2, face=(3.0, 2.0))
            assert await b.state(f"{STOPS}[1].yaw_rad") == pytest.approx(math.pi / 2, abs=0.1)
            await b.click_map(*wall_point(app, (4.0, -1.0)))
            await b.wait_js("document.querySelector('#stopEditMsg').textContent"
                            ".includes('inside an obstacle')")
            assert await page.is_disabled("#stopSave")
            await b.shot("tour-refused")
            await add_stop(b, (4.0, -1.0), "Fountain", 3)
            # Drag a stop to move it; reorder; edit its stay and message.
            await drag_stop(b, (2.0, -2.0), (2.5, -2.5))
            await b.wait_js(f"Math.abs({STOPS}[0].x_m - 2.5) < 0.1")
            await page.locator("#tourStops li").nth(0).get_by_title("visit later").click()
            await b.wait_js(f"{STOPS}.map(s => s.name).join() === 'Window,Desk,Fountain'")
            await page.locator("#tourStops li").nth(2).get_by_title("edit name, stay, message"
                                                                    ).click()
            await page.fill("#stopDwell", "20")
            await page.fill("#stopText", "The fountain was built in 1890.")
            await page.click("#stopSave")
            await b.wait_js(f"{STOPS}[2].dwell_s === 20")
            est = await b.text("#tourEstimate")
            assert "3 stops" in est and "home to home" in est
            await b.shot("tour-map")
            await b.shot("tours", "#toursCard")

            # Duplicate, then delete the copy (asked first).
            await page.click("#tourDup")
            await b.wait_js(f"{TOURS}.list.some(t => t.name === 'Garden walk (copy)')")
            await page.click("#tourDel")
            await b.confirm("Delete the tour “Garden walk (copy)”", accept=True)
            await b.wait_js(f"!{TOURS}.list.some(t => t.name === 'Garden walk (copy)')")
            walk = next(t for t in app.tours.store.list_tours() if t.name == "Garden walk")
            assert [s.name for s in walk.stops] == ["Window", "Desk", "Fountain"]
            assert walk.stops[2].message.text == "The fountain was built in 1890."
            assert (walk.stops[1].x_m, walk.stops[1].y_m) == pytest.approx((2.5, -2.5), abs=0.1)

            # Schedule it at 10:00 on Mondays (the building's time); an overlap is refused.
            await page.click("#scheduleCard summary")
            await b.wait_js("document.querySelector('#schedClock').textContent"
                            ".includes('09:5')")
            await page.select_option("#schedTour", str(walk.id))
            await page.check(".days input[value=mon]")
            await page.fill("#schedTimes", "10:00")
            await page.click("#schedAdd")
            await b.wait_js("[...document.querySelectorAll('#upcoming li')].some(li => "
                            "li.textContent.includes('10:00 · Garden walk'))")
            b.allowed.append("status of 400")  # the refusal, as the browser logs it
            await page.check(".days input[value=mon]")
            await page.fill("#schedTimes", "10:02")
            await page.click("#schedAdd")
            await b.wait_js("document.querySelector('#schedMsg').textContent"
                            ".includes('Overlapping schedules')")
            assert "or later" in await b.text("#schedMsg")
            await b.shot("schedule", "#scheduleCard")

            # The building's clock reaches 10:00: the scheduler starts it, the page says so.
            events = app.bus.subscribe(EVENTS)
            clock.jump_wall(dt.datetime(2025, 6, 2, 9, 59, 55, tzinfo=LONDON).timestamp()
                            - clock.wall_time())
            assert await clock.wait_until(
                lambda: any(e.kind == "tour.scheduled_start" for e in events.drain()),
                timeout_s=60.0)
            await b.wait_js("window.curio.S.tour && window.curio.S.tour.name === 'Garden walk'")
            await b.wait_js("[...document.querySelectorAll('#events li')].some(li => "
                            "li.textContent.includes('Scheduled tour “Garden walk” (10:00)'))")
            await b.wait_js("document.querySelector('#toursSummary').textContent"
                            ".includes('Garden walk')")  # the card follows the running tour
            assert b.errors == []


async def test_the_kiosk_starts_an_offered_tour_and_follows_it(tmp_path: Path,
                                                               viewport: str) -> None:
    """The kiosk page with the kiosk token: only offered tours, a start with a kiosk:<name>
    source, the stop's name and message in large type and when the rover moves on, Stop the
    tour; a tablet in portrait and landscape. Drives: tours, behaviour tree, navigation, sim."""
    cfg = make_cfg(tmp_path / "data", 'bt.tree="tour"',
                   'bt.tour_stops=[{name="Lobby", x_m=2.0, y_m=-2.0, dwell_s=20.0, '
                   'message="Welcome to the Curio building!"}, {name="Desk", x_m=3.0, y_m=1.0, '
                   'dwell_s=5.0}]')
    kiosk = add_token(cfg, "lobby", "kiosk")
    async with running_app(cfg) as (app, _clock):
        app.tours.store.rename(1, "Highlights")
        app.tours.store.duplicate(1, "Staff only")  # a draft: not offered at the kiosk
        ops = app.bus.subscribe(OPERATOR)
        base = (app.web_url or "").split("?")[0]
        async with chromium() as browser:
            b = await open_page(browser, base + f"kiosk?token={kiosk}", viewport,
                                connected=False)
            page = b.page
            await b.wait_js("document.querySelectorAll('.kTour').length === 1 && "
                            "!document.querySelector('.kTour').disabled")
            assert "Highlights" in await b.text(".kTour")
            assert await page.locator("button").count() == 4  # the tour, Stop, the box's two
            await b.shot("kiosk-choose")
            await page.click(".kTour")
            await b.wait_js("document.querySelector('#kNotice').textContent.includes('starts')")
            (cmd,) = ops.drain()
            assert (cmd.action, cmd.tour_id, cmd.source) == ("start_tour", 1, "kiosk:lobby")
            await b.wait_js("!document.querySelector('#kRunning').classList.contains('hidden')")
            await b.wait_js("document.querySelector('#kStop').textContent === 'Lobby'",
                            timeout_s=60)
            assert "Welcome to the Curio building!" in await b.text("#kMessage")
            assert "Next stop: Desk" in await b.text("#kNext")
            await b.shot("kiosk-tour")
            if viewport == "desktop":  # and a tablet in both orientations, same moment
                for name, size in (("portrait", (800, 1280)), ("landscape", (1280, 800))):
                    tab = await browser.new_context(**{**VIEWPORTS["phone"], "viewport": {
                        "width": size[0], "height": size[1]}, "device_scale_factor": 1})
                    tp = Browser(await tab.new_page(), f"tablet-{name}")
                    await tp.page.goto(base + f"kiosk?token={kiosk}")
                    await tp.wait_js("document.querySelector('#kStop').textContent === 'Lobby'")
                    await tp.shot("kiosk")
                    assert tp.errors == []
                    await tab.close()
            await page.click("#kStopTour")
            await b.confirm("Stop the tour?", accept=True)
            await b.wait_js("document.querySelector('#kRunning').classList.contains('hidden')",
                            timeout_s=30)
            assert [(c.action, c.source) for c in ops.drain()] == [("stop_tour", "kiosk:lobby")]
            assert b.errors == []
