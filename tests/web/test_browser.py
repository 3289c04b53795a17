"""End-to-end: the whole App on a real-time SimClock, driven through Debian's Chromium on a
desktop (1280×800) and a phone (390×844) viewport — the operator's controls, the map tools,
HELP ME, driving by hand and the e-stop, tours from a kiosk token. Screenshots of every panel
go to ``artifacts/screenshots/<viewport>-<panel>.png`` (gitignored). Each test says which parts
of the App it drives; every wait is for a condition.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from curio.core.topics import CMD_VEL, CMD_VEL_TELEOP, ESTOP, INITIAL_POSE, OPERATOR
from tests.web.browser_kit import (
    TELEOP_SPEED,
    add_token,
    browser_on,
    make_cfg,
    running_app,
    truth_xy,
)

pytestmark = [pytest.mark.browser]


async def test_operator_controls_drive_the_rover(tmp_path: Path, viewport: str) -> None:
    """A goal clicked on the map moves the rover and the message is the rover's own answer;
    a goal off the map is refused on the page; Pause/Resume; Go Home lit only while going home;
    a bad path number says why. Drives: sim, estimation, navigation, behaviour tree."""
    async with running_app(make_cfg(tmp_path / "data")) as (app, clock), \
            browser_on(app.web_url or "", viewport) as b:
        page = b.page
        assert "admin" in await b.text("#who")
        await b.wait_js("window.curio.S.images.map && window.curio.S.pose")
        await b.shot("map")
        # The costmap overlay is fetched (as a PNG) only when it is switched on.
        assert await b.state("!window.curio.S.images.costmap")
        await page.click("#layers summary")
        await page.check("#showCostmap")
        await b.wait_js("!!window.curio.S.images.costmap")
        await b.shot("layers")
        await page.uncheck("#showCostmap")
        await page.click("#layers summary")

        # A bad path number: a visible, specific message, nothing sent.
        await page.fill("#pathInput", "7")
        await page.press("#pathInput", "Enter")
        await b.wait_js("document.querySelector('#pathMsg').textContent.includes('no path 7')")
        assert "paths are 0–2" in await b.text("#pathMsg")
        await page.fill("#pathInput", "two")
        await page.click("#pathEnter")
        await b.wait_js("document.querySelector('#pathMsg').textContent.includes('not a path')")
        await b.shot("controls", "#controls")

        # Off the map: refused on the page, nothing sent.
        ops = app.bus.subscribe(OPERATOR)
        await page.click("[data-tool=goal]")
        await page.click("#fit")
        await page.click("#zoomOut")
        origin = await b.state("window.curio.S.grids.map.origin")
        await b.click_map(origin[0] - 1.0, origin[1] + 1.0)
        await b.wait_js("document.querySelector('#toast').textContent.includes('off the map')")
        assert "x from" in await b.text("#toast")
        assert ops.drain() == []

        # Send the rover to a point by clicking the map: the answer is the rover's.
        start = truth_xy(app)
        await b.click_map(start[0] + 2.0, start[1])
        await b.wait_js("window.curio.S.status.state === 'moving'")
        await b.wait_js("document.querySelector('#cmdMsg').className.includes('ok')")
        assert "waiting" not in await b.text("#cmdMsg")
        await b.wait_js("window.curio.S.goal !== null")  # the goal flag
        await b.wait_js(f"window.curio.S.pose && Math.hypot(window.curio.S.pose.x - {start[0]},"
                        f" window.curio.S.pose.y - {start[1]}) > 0.3", timeout_s=30)
        await b.wait_js("window.curio.S.trail.length >= 6")  # the trail behind it
        await b.shot("moving")

        # Pause: the button and the badge follow the rover's real state.
        await page.click("#pause")
        await b.wait_js("window.curio.S.status.state === 'paused'")
        await b.wait_js("document.querySelector('#pause').textContent.includes('Resume')")
        assert await b.text("#stateBadge") == "Paused"
        await clock.sleep(1.0)
        x0 = truth_xy(app)
        await clock.sleep(1.0)
        assert math.dist(x0, truth_xy(app)) < 0.05, "the rover kept moving while paused"
        await page.click("#pause")
        await b.wait_js("window.curio.S.status.state !== 'paused'")
        await b.wait_js("document.querySelector('#pause').textContent.includes('Pause')")

        # Go Home is lit while going home, and no longer once home.
        await page.click("#goHome")
        await b.wait_js("window.curio.S.status.state === 'going_home'")
        assert "on" in (await page.get_attribute("#goHome", "class") or "")
        home = app.cfg.robot.home
        assert await clock.wait_until(
            lambda: math.dist(truth_xy(app), home[:2]) < 0.35, timeout_s=90.0), \
            f"not home: {truth_xy(app)}"
        await b.wait_js("window.curio.S.status.state === 'arrived'", timeout_s=30)
        await b.wait_js("!document.querySelector('#goHome').classList.contains('on')")
        await b.wait_js("window.curio.S.goal === null")
        await b.shot("home")
        assert b.errors == []


async def test_path_editor_and_map_tools(tmp_path: Path, viewport: str) -> None:
    """Waypoints clicked (one with a heading), dragged, inserted on a leg, reordered and
    removed persist over a restart; a waypoint off the map is refused; the measure tool, the
    cursor's coordinates and the adaptive scale bar; the pose tool's answer is the rover's new
    pose. Drives: behaviour tree (path manager), simulator (map), localisation."""
    data = tmp_path / "data"
    async with running_app(make_cfg(data)) as (app, clock), \
            browser_on(app.web_url or "", viewport) as b:
        page = b.page
        await b.wait_js("window.curio.S.images.map && window.curio.S.pose")
        await b.look_at(1.5, 0.3, 60.0)  # the area to edit, zoomed in on any screen
        await page.click("#pathsCard summary")
        await page.click("#newPath")
        await b.wait_js("window.curio.S.editPathId !== null")
        new_id = await b.state("window.curio.S.editPathId")
        wps = f"window.curio.S.paths.find(p => p.id === {new_id}).waypoints"
        assert await b.state("document.querySelector('.tool.active').dataset.tool") == "waypoint"
        await b.click_map(1.0, 0.5)
        await b.wait_js(f"{wps}.length === 1")
        await b.click_map(2.0, 1.0, drag_to=(2.0, 2.0))  # drag: the waypoint faces +y
        await b.wait_js(f"{wps}.length === 2")
        await b.click_map(3.0, -1.0)
        await b.wait_js(f"{wps}.length === 3")
        # Drag waypoint 3 to a new place; click the leg between 1 and 2 to insert one there.
        await b.click_map(3.0, -1.0, drag_to=(3.0, -0.5))
        await b.wait_js(f"Math.abs({wps}[2].y_m + 0.5) < 0.05")
        await b.click_map(1.5, 0.75)
        await b.wait_js(f"{wps}.length === 4")
        assert await b.state(f"{wps}.map(w => w.x_m)") == pytest.approx([1.0, 1.5, 2.0, 3.0],
                                                                         abs=0.05)
        await page.locator("#waypoints li").nth(1).get_by_title("move later").click()
        await b.wait_js(f"{wps}[1].x_m > 1.9")
        await page.locator("#waypoints li").nth(3).get_by_title("remove this waypoint").click()
        await b.wait_js(f"{wps}.length === 3")
        # A waypoint off the map is refused on the page.
        await page.click("#fit")
        await page.click("#zoomOut")
        origin = await b.state("window.curio.S.grids.map.origin")
        await b.click_map(origin[0] - 1.0, origin[1] + 2.0)
        await b.wait_js("document.querySelector('#toast').textContent.includes('off the map')")
        assert await b.state(f"{wps}.length") == 3
        await page.fill("#pathName", "Lab visit")
        await page.click("#renamePath")
        await b.wait_js(f"window.curio.S.paths.find(p => p.id === {new_id}).name === 'Lab visit'")
        await b.shot("paths", "#pathsCard")

        # Measure, cursor coordinates, the scale bar that adapts to the zoom.
        await b.look_at(1.5, 1.5, 40.0)
        await page.click("[data-tool=measure]")
        await b.click_map(0.0, 0.0, drag_to=(3.0, 4.0))
        assert await b.state("Math.hypot(window.curio.measure.bx - window.curio.measure.ax,"
                             " window.curio.measure.by - window.curio.measure.ay)") == \
            pytest.approx(5.0, abs=0.1)
        await page.mouse.move(*await b.map_point(2.0, -1.0))
        cursor = await b.text("#cursor")
        assert "x 2.0" in cursor or "x 1.9" in cursor, cursor
        await b.shot("measure")
        bar = await b.state("window.curio.scaleBarM")
        for _ in range(4):
            await page.click("#zoomIn")
        await b.wait_js(f"window.curio.scaleBarM < {bar}")

        # The pose tool: an initial pose, then the rover's answer (its new pose).
        poses = app.bus.subscribe(INITIAL_POSE)
        await page.click("[data-tool=pose]")
        await page.click("#fit")
        x, y = truth_xy(app)
        await b.click_map(x, y, drag_to=(x + 1.0, y))  # where it is, facing +x (as it does)
        assert await clock.wait_until(lambda: len(poses) > 0, timeout_s=10.0)
        (initial,) = poses.drain()
        assert (initial.pose.x, initial.pose.y) == pytest.approx((x, y), abs=0.06)
        assert abs(initial.pose.yaw) < 0.05
        await b.wait_js("document.querySelector('#cmdMsg').textContent.includes("
                        "'took the new position')")
        assert b.errors == []

    async with running_app(make_cfg(data)) as (app, _clock):
        saved = app.paths.get(new_id)
        assert saved.name == "Lab visit"
        assert [(round(w.x_m, 1), round(w.y_m, 1)) for w in saved.waypoints] == \
            [(1.0, 0.5), (2.0, 1.0), (1.5, 0.8)]
        assert saved.waypoints[0].yaw_rad is None
        assert saved.waypoints[1].yaw_rad == pytest.approx(math.pi / 2, abs=0.05)


async def test_blocked_door_shows_help_me_what_blocks_and_a_sound(tmp_path: Path,
                                                                 viewport: str) -> None:
    """The library door closes in front of the rover driving a path typed by number: HELP ME
    blinks, what blocks it is drawn, a sound plays (and stops when muted); the door reopens:
    Thanks!. Drives: sim world (doors), navigation (blocked detector), behaviour tree.

    The recovery ladder is cut to ``wait`` and the no-progress time to 2 s so that the help
    request comes before the navigator gives the goal up.
    """
    cfg = make_cfg(tmp_path / "data", "sim.start=[1.55, 7.9, 1.5708]",
                   "nav.blocked.no_progress_s=2", 'nav.recovery.ladder=["wait"]',
                   "nav.recovery.wait_s=10")
    async with running_app(cfg) as (app, clock), browser_on(app.web_url or "", viewport) as b:
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
        assert await b.text("#stateBadge") == "Needs help"
        await b.wait_js("window.curio.S.blocker && window.curio.S.blocker.points.length > 0")
        door_y = await b.state("window.curio.S.blocker.points.reduce((a, p) => a + p[1], 0) /"
                               " window.curio.S.blocker.points.length")
        assert door_y > truth_xy(app)[1]  # what blocks it is ahead, towards the library
        await b.wait_js("window.curio.sound.beeps >= 1", timeout_s=10)
        await b.shot("help-me")
        await page.click("#mute")
        beeps = await b.state("window.curio.sound.beeps")
        ticks = await b.state("window.curio.sound.ticks")
        await b.wait_js(f"window.curio.sound.ticks >= {ticks} + 2", timeout_s=15)
        assert await b.state("window.curio.sound.beeps") == beeps  # muted: silent
        app.world.set_door("library", True)
        await b.wait_js("document.querySelector('#help').textContent === 'Thanks!'",
                        timeout_s=60)
        await b.wait_js("window.curio.S.blocker === null")
        await b.shot("thanks")
        assert b.errors == []


async def test_teleop_lease_speed_and_the_estop(tmp_path: Path, viewport: str) -> None:
    """Hold the joystick: the rover drives at the chosen speed, STOP, the status line and the
    map stay in view (a phone too); let go: it stops. Escape in a text box does not e-stop,
    outside it does; STOP works after a burst of refused commands; releasing asks first and
    says who set and released it; the arrow keys drive with the same deadman. Drives: sim,
    safety stage."""
    async with running_app(make_cfg(tmp_path / "data"), TELEOP_SPEED) as (app, clock), \
            browser_on(app.web_url or "", viewport) as b:
        page = b.page
        await b.wait_js("window.curio.S.pose")
        teleop = app.bus.subscribe(CMD_VEL_TELEOP, maxsize=1000)
        await page.evaluate("() => window.curio.setSpeed(50)")
        start = truth_xy(app)
        joy = await page.locator("#joystick").bounding_box()
        cx, cy = joy["x"] + joy["width"] / 2, joy["y"] + joy["height"] / 2
        await page.mouse.move(cx, cy)
        await page.mouse.down()
        await page.mouse.move(cx, cy - joy["height"] * 0.6, steps=4)
        assert await clock.wait_until(
            lambda: math.dist(start, truth_xy(app)) > 0.15, timeout_s=10.0), \
            "the rover did not move under teleop"
        for element in ("#estop", "#statusText", "#map", "#joystick"):
            assert await b.in_view(element), f"{element} is not in view while driving"
        await b.wait_js("document.querySelector('#stateBadge').textContent === 'Driving by hand'")
        assert "You are driving" in await b.text("#leaseText")
        await b.shot("teleop")
        await b.shot("drive", "#drivePane")
        await page.mouse.up()
        limit = min(app.cfg.robot.max_wheel_speed_mps, app.cfg.nav.safety.max_speed_mps)
        fastest = max(abs(m.linear_mps) for m in teleop.drain())
        assert fastest == pytest.approx(0.5 * limit, abs=0.02)  # the 50 % speed setting
        await clock.sleep(1.0)  # deadman: stopped within the safety timeout and ramp
        cmd = app.bus.latest(CMD_VEL)
        assert cmd is not None and abs(cmd.linear_mps) < 1e-3
        held = truth_xy(app)
        await clock.sleep(1.0)
        assert math.dist(held, truth_xy(app)) < 0.02, "the rover kept moving after release"

        # Escape inside a text box only leaves the box; outside it, it is the e-stop.
        ops = app.bus.subscribe(OPERATOR)
        await page.click("#pathInput")
        await page.keyboard.press("Escape")
        await page.click("#pathInput")
        await page.keyboard.type("12")
        await page.keyboard.press("Escape")
        assert not [c for c in ops.drain() if c.action == "estop"]
        assert not await b.state("!!(window.curio.S.estop && window.curio.S.estop.engaged)")
        # A burst of commands (refused for speed) does not block STOP.
        b.allowed.append("status of 429")  # the browser logs each refused request
        statuses = await page.evaluate("""async () => {
            const h = {"Content-Type": "application/json",
                       "Authorization": "Bearer " + window.curio.S.token};
            const all = [];
            for (let i = 0; i < 120; i++) all.push(fetch("/api/command", {method: "POST",
                headers: h, body: JSON.stringify({action: "pause"})}).then(r => r.status));
            return Promise.all(all);
        }""")
        assert 429 in statuses
        await page.locator("body").press("Escape")
        await b.wait_js("window.curio.S.estop && window.curio.S.estop.engaged")
        pressed = [c for c in ops.drain() if c.action == "estop"]
        engaged = app.bus.latest(ESTOP)
        assert len(pressed) == 1  # sent over the WebSocket and REST, published once
        assert engaged is not None and engaged.engaged
        # It reached the safety stage within one control cycle (at once, in fact).
        assert engaged.stamp - pressed[0].stamp <= 1.0 / app.cfg.nav.safety.rate_hz
        assert "by admin" in await b.text("#estopWho")
        assert await page.is_visible("#estopBanner")
        assert await b.text("#stateBadge") == "E-STOP"
        await b.shot("estop")
        held = truth_xy(app)
        await page.mouse.move(cx, cy)
        await page.mouse.down()
        await page.mouse.move(cx, cy - joy["height"] * 0.4, steps=4)
        await clock.sleep(1.5)
        await page.mouse.up()
        assert math.dist(held, truth_xy(app)) < 0.02, "the rover moved during an e-stop"

        # Releasing asks first; "keep it stopped" keeps it; the release shows who and when.
        await page.click("#releaseEstop")
        await b.wait_js("!document.querySelector('#modal').classList.contains('hidden')")
        await b.shot("release-confirm")
        await b.confirm("Release the emergency stop set by admin", accept=False)
        assert await b.state("window.curio.S.estop.engaged")
        await page.click("#releaseEstop")
        await b.confirm("Release the emergency stop", accept=True)
        await b.wait_js("window.curio.S.estop && !window.curio.S.estop.engaged")
        assert not await page.is_visible("#estopBanner")
        await b.wait_js("document.querySelector('#estopLog').textContent.includes('released by')")
        assert app.bus.latest(ESTOP) is not None and not app.bus.latest(ESTOP).engaged

        # The keyboard drives too (arrow keys), with the same deadman.
        start = truth_xy(app)
        await page.locator("#map").focus()
        await page.keyboard.down("ArrowUp")
        assert await clock.wait_until(
            lambda: math.dist(start, truth_xy(app)) > 0.15, timeout_s=10.0), \
            "the rover did not move with the arrow key held"
        await page.keyboard.up("ArrowUp")
        await clock.sleep(1.0)
        held = truth_xy(app)
        await clock.sleep(1.0)
        assert math.dist(held, truth_xy(app)) < 0.02, "the rover kept moving after the key"
        # On every viewport STOP and the status stay in view wherever the page is scrolled.
        await page.locator("#logCard").scroll_into_view_if_needed()
        assert await b.in_view("#estop") and await b.in_view("#statusText")
        assert b.errors == []


async def test_kiosk_token_starts_and_stops_tours_only(tmp_path: Path, viewport: str) -> None:
    """A kiosk token: Start tour and Stop this trip work (from the tree's state), everything
    else is disabled and says why. Drives: behaviour tree (tour), navigation, sim."""
    cfg = make_cfg(tmp_path / "data", 'bt.tree="tour"',
                   'bt.tour_stops=[{name="Lobby", x_m=2.0, y_m=-2.5, dwell_s=1.0, '
                   'message="Welcome"}]')
    kiosk = add_token(cfg, "lobby", "kiosk")
    async with running_app(cfg) as (app, _clock):
        url = (app.web_url or "").split("?")[0] + f"?token={kiosk}"
        async with browser_on(url, viewport) as b:
            page = b.page
            ops = app.bus.subscribe(OPERATOR)
            assert "lobby" in await b.text("#who")
            for button in ("#goHome", "#pause", "#pathEnter", "#estop"):
                assert await page.is_disabled(button), button
            assert await page.is_visible("#startTour")
            assert not await page.is_visible("#cancelTrip")
            await page.click("#startTour")
            await b.wait_js("['tour', 'moving'].includes(window.curio.S.status.state)")
            await b.wait_js("document.querySelector('#cmdMsg').textContent.includes("
                            "'Tour started')")
            await b.wait_js("!document.querySelector('#cancelTrip').classList.contains('hidden')")
            await b.shot("kiosk")
            await page.click("#cancelTrip")
            await b.wait_js("window.curio.S.status.state === 'idle'")
            assert not await page.is_visible("#cancelTrip")
            assert [(c.action, c.source) for c in ops.drain()] == [
                ("start_tour", "kiosk:lobby"), ("stop_tour", "kiosk:lobby")]
            assert b.errors == []
