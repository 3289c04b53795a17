"""The dashboard's unattended-operation and people features through the real page (Chromium,
desktop 1280×800 and phone 390×844): the battery chip follows the simulated pack (low and
critical styled), Dock / Undock drive the real docking behaviour, Relocalise and "Set position"
(with its spread) reach the localiser and the lost state shows on the dashboard and the kiosk,
a help request shows its bar, wait and chime, and what blocks the rover, a zone drawn on the
map is saved (and a refused one shows the rover's sentence), and the people layer draws the
tracks in a crowd. Screenshots of each state in ``artifacts/screenshots/``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.bus import Subscription
from curio.core.clock import SimClock
from curio.core.messages import HelpState, Obstacles, PoseWithCovariance
from curio.core.topics import HELP, HELP_BLOCKAGE, INITIAL_POSE
from tests.web import browser_kit as kit

pytestmark = [pytest.mark.browser]

BAR_KIND = "document.querySelector('#uBar').dataset.kind"


async def _next(clock: SimClock, sub: Subscription[PoseWithCovariance]) -> PoseWithCovariance:
    """The next initial pose the page sent (within 5 s of simulated time)."""
    got: list[PoseWithCovariance] = []
    def arrived() -> bool:
        got.extend(sub.drain())
        return bool(got)

    assert await clock.wait_until(arrived, timeout_s=5.0)
    return got[-1]


async def test_battery_and_dock(tmp_path: Path, viewport: str) -> None:
    """The rover starts on its dock: Undock backs it out, Dock docks it again (the real
    behaviour: staging, the lidar-aligned approach, the charger's contact); the battery chip
    shows charge and charging, then low and critical as the simulated pack runs down.
    Drives: simulator (dock, battery), power monitor, docker, behaviour tree, navigator."""
    cfg = kit.make_cfg(tmp_path / "data", "dock.enabled=true")
    async with kit.running_app(cfg) as (app, _), \
            kit.browser_on(app.web_url or "", viewport) as b:
        assert app.world is not None and app.docker is not None
        await b.wait_js("window.curio.U.power && window.curio.U.dockInfo && window.curio.U.dock")
        await b.wait_js("document.querySelector('#uDock').dataset.state === 'docked'")
        assert "charging" in await b.text("#batteryChip") or "⚡" in await b.text("#batteryChip")
        await b.look_at(0.0, 0.0, 90.0)
        await b.shot("dock-docked", "#careCard")

        await b.page.click("#uUndockBtn")
        await b.wait_js("['undocking', 'idle'].includes(window.curio.U.dock.state)")
        await b.wait_js("window.curio.U.dock.state === 'idle'", timeout_s=40)
        assert not app.docker.docked
        await b.wait_js("!document.querySelector('#uDockBtn').disabled")
        await b.page.click("#uDockBtn")
        await b.wait_js("['staging', 'approaching'].includes(window.curio.U.dock.state)")
        await b.shot("dock-docking", "#careCard")
        await b.wait_js("window.curio.U.dock.state === 'docked'", timeout_s=90)
        assert app.docker.docked
        assert "on the dock" in await b.text("#uDock")

        # The pack runs down: the chip says so, styled (low, then critical).
        soc_full = await b.state("window.curio.U.power.soc")
        chip_full = await b.text("#batteryChip")
        app.world.set_battery_voltage(6.45)
        await b.wait_js("document.querySelector('#batteryChip').dataset.level === 'low'",
                        timeout_s=30)
        await b.wait_js(f"window.curio.U.power.soc < {soc_full} - 0.3", timeout_s=30)  # filtered
        await b.wait_js(f"document.querySelector('#batteryChip').textContent !== {chip_full!r}")
        assert "bad" in (await b.page.get_attribute("#batteryChip", "class") or "")
        await b.shot("battery-low")
        app.world.set_battery_voltage(6.0)
        await b.wait_js("document.querySelector('#batteryChip').dataset.level === 'critical'",
                        timeout_s=30)
        assert "critical" in (await b.page.get_attribute("#batteryChip", "class") or "")
        await b.shot("battery-critical", "#careCard")
        assert b.errors == []


async def test_relocalise_set_pose_and_lost(tmp_path: Path, viewport: str) -> None:
    """Relocalise sends a whole-map search; "Set position" sends the pose with the chosen
    spread; the lost localiser shows as the amber bar on the dashboard and as "looking around"
    on the kiosk, and both go once it is found. Drives: localiser, hub, the kiosk page."""
    cfg = kit.make_cfg(tmp_path / "data")
    async with kit.running_app(cfg) as (app, clock), kit.chromium() as browser:
        b = await kit.open_page(browser, app.web_url or "", viewport)
        kiosk = await kit.open_page(browser, (app.web_url or "").split("?")[0] + "kiosk",
                                    viewport, connected=False)
        await kiosk.wait_js("window.curio.S.connected")
        poses = app.bus.subscribe(INITIAL_POSE, maxsize=10)
        await b.wait_js("window.curio.S.pose && window.curio.S.images.map")
        await b.page.click("#uRelocalise")
        await b.wait_js("document.querySelector('#uMsg').textContent.includes('whole map')")
        sent = await _next(clock, poses)
        assert sent.covariance[0] > 1e5, "relocalise must search the whole map"
        # The localiser has forgotten where it is: both pages say so while it searches.
        await b.wait_js(f"{BAR_KIND} === 'lost' && document.querySelector('#uBar')"
                        ".textContent.includes('looking around')", timeout_s=10)
        await b.page.evaluate("() => window.scrollTo(0, 0)")
        await b.shot("lost")
        await kiosk.wait_js("!document.querySelector('#kLost').classList.contains('hidden')",
                            timeout_s=10)
        assert "looking around" in await kiosk.text("#kLost")
        await kiosk.shot("kiosk-lost")

        # Set the pose with a spread of 0.5 m by dragging on the map.
        x, y = kit.truth_xy(app)
        await b.page.select_option("#uSpread", "0.5")
        await b.page.click("#uSetPose")
        assert await b.state("window.curio.tool") == "pose"
        await b.look_at(x, y, 60.0)
        await b.click_map(x, y, drag_to=(x + 0.8, y))
        sent = await _next(clock, poses)
        assert sent.covariance[0] == pytest.approx(0.25, rel=1e-3)  # (0.5 m)²
        assert sent.pose.x == pytest.approx(x, abs=0.1) and abs(sent.pose.yaw) < 0.2
        # Found again: the bar goes, and so does the kiosk's note.
        await b.wait_js(f"{BAR_KIND} !== 'lost'", timeout_s=30)
        assert await b.text("#statusText") == "I know where I am again."
        await kiosk.wait_js("document.querySelector('#kLost').classList.contains('hidden')",
                            timeout_s=30)
        assert b.errors == [] and kiosk.errors == []


async def test_help_bar_chime_and_blockage(tmp_path: Path, viewport: str) -> None:
    """A help request (as the help desk publishes it) shows the red bar with the reason and the
    wait, chimes (after the operator touched the page, as browsers require) and again at a
    repeat, draws what blocks the rover; the test notification answers. Drives: hub, the
    unattended socket, the help desk (notification test)."""
    cfg = kit.make_cfg(tmp_path / "data")
    async with kit.running_app(cfg) as (app, clock), \
            kit.browser_on(app.web_url or "", viewport) as b:
        await b.wait_js("window.curio.S.pose && window.curio.U.power")
        await b.page.click("#mute")  # a gesture: the page may play sound now
        await b.page.click("#mute")
        x, y = kit.truth_xy(app)
        since = clock.now() - 75.0
        message = "Excuse me, could you help me? My way is blocked."
        app.bus.publish(HELP_BLOCKAGE, Obstacles(clock.now(), circles=tuple(
            (x + 1.0, y + dy, 0.05) for dy in (-0.2, -0.1, 0.0, 0.1, 0.2))))
        app.bus.publish(HELP, HelpState(clock.now(), True, "blocked", message, since, 0, True,
                                        (x + 1.0, y)))
        await b.wait_js(f"{BAR_KIND} === 'help'")
        bar = await b.text("#uBar")
        assert message in bar and "waiting 1 min 1" in bar, bar  # 75 s and counting
        await b.wait_js("window.curio.U.chimesAsked === 1")
        app.bus.publish(HELP, HelpState(clock.now(), True, "blocked", message, since, 1, True,
                                        (x + 1.0, y)))
        await b.wait_js("window.curio.U.chimesAsked === 2")
        assert await b.state("window.curio.U.chimesPlayed") >= 1, "no chime after a gesture"
        assert "asked 2 times" in await b.text("#uBar")
        await b.look_at(x + 0.5, y, 80.0)
        await b.page.evaluate("() => window.scrollTo(0, 0)")
        await b.shot("help")

        await b.page.evaluate("() => document.getElementById('uNotify')"
                              ".scrollIntoView({block: 'center'})")  # below the sticky bars
        await b.page.click("#uNotify")
        await b.wait_js("document.querySelector('#uMsg').textContent.includes('Test notification')")
        assert "no channel is configured" in await b.text("#uMsg")
        app.bus.publish(HELP, HelpState(clock.now()))
        await b.wait_js(f"{BAR_KIND} !== 'help'")
        assert b.errors == []


async def test_help_bar_when_a_door_closes(tmp_path: Path, viewport: str) -> None:
    """The real blocked-door situation: the library door closes in front of the rover on a
    path; the help desk's request shows in the red bar (its own words, the wait), chimes, and
    the clearance probe's blocking points are drawn; the door reopens: the bar goes. Drives:
    sim world (doors), navigation, behaviour tree, help desk, clearance probe. (Setup as in
    test_browser.py's blocked-door test: recovery cut to ``wait`` so help comes first.)"""
    cfg = kit.make_cfg(tmp_path / "data", "sim.start=[1.55, 7.9, 1.5708]",
                       "nav.blocked.no_progress_s=2", 'nav.recovery.ladder=["wait"]',
                       "nav.recovery.wait_s=10")
    async with kit.running_app(cfg) as (app, clock), \
            kit.browser_on(app.web_url or "", viewport) as b:
        assert app.world is not None
        pid = app.paths.create("Library").id
        app.paths.add_waypoint(pid, 1.2, 11.5)
        await b.wait_js(f"window.curio.S.paths.some(p => p.id === {pid}) && window.curio.S.pose")
        await b.page.fill("#pathInput", str(pid))
        await b.page.press("#pathInput", "Enter")
        await b.wait_js("window.curio.S.status.state === 'moving'")
        assert await clock.wait_until(lambda: kit.truth_xy(app)[1] > 8.1, timeout_s=20.0)
        app.world.set_door("library", False)
        await b.wait_js(f"{BAR_KIND} === 'help' && window.curio.U.help &&"
                        " window.curio.U.help.active", timeout_s=60)
        bar = await b.text("#uBar")
        said = await b.state("window.curio.U.help.message")
        assert await b.state("window.curio.U.help.reason") == "blocked"
        assert said and said in bar and "waiting" in bar, bar  # the request in its own words
        assert await b.state("window.curio.U.chimesAsked") >= 1
        await b.wait_js("window.curio.U.blockage && window.curio.U.blockage.circles.length > 0",
                        timeout_s=20)
        door_y = await b.state("Math.min(...window.curio.U.blockage.circles.map(c => c[1]))")
        assert door_y > kit.truth_xy(app)[1]  # what blocks it is ahead, in the doorway
        await b.look_at(1.4, 9.0, 70.0)
        await b.page.evaluate("() => window.scrollTo(0, 0)")
        await b.shot("help-door")
        app.world.set_door("library", True)
        await b.wait_js(f"{BAR_KIND} !== 'help'", timeout_s=60)
        assert b.errors == []


ZONE = [(1.5, 2.0), (2.5, 2.0), (2.5, 3.0), (1.5, 3.0)]


async def _draw(b: kit.Browser, corners: list[tuple[float, float]]) -> None:
    await b.page.click("#zDraw")
    assert await b.state("window.curio.tool") == "zones"
    for cx, cy in corners:
        await b.click_map(cx, cy)
    await b.click_map(*corners[0])  # the first corner again closes the shape
    await b.wait_js("window.curio.Z.draft && window.curio.Z.draft.closed")


async def test_zone_drawn_saved_refused_deleted(tmp_path: Path, viewport: str) -> None:
    """A speed zone drawn by clicking its corners is saved (GET /api/zones has it) and drawn on
    the map; a keep-out zone over the rover is refused with the rover's sentence; the zone is
    chosen and deleted. Drives: the zone service (store, costmap), the page's editor."""
    cfg = kit.make_cfg(tmp_path / "data")
    async with kit.running_app(cfg) as (app, _), \
            kit.browser_on(app.web_url or "", viewport) as b:
        assert app.zones is not None
        await b.wait_js("window.curio.S.pose && window.curio.S.images.map")
        await b.page.click("#zonesCard > summary")
        await b.look_at(2.0, 2.5, 70.0)
        await _draw(b, ZONE)
        await b.page.select_option("#zKind", "speed")
        await b.page.fill("#zSpeed", "0.3")
        await b.page.fill("#zName", "Gallery slow")
        await b.shot("zone-drawn", "#zonesCard")
        await b.page.click("#zSave")
        await b.wait_js("window.curio.Z.zones.length === 1 && !window.curio.Z.draft")
        zones = app.zones.list_zones()["zones"]
        assert [(z["name"], z["kind"], z["speed_limit_mps"]) for z in zones] == [
            ("Gallery slow", "speed", pytest.approx(0.3))]
        assert [v for c in zones[0]["polygon"] for v in c] == pytest.approx(
            [v for c in ZONE for v in c], abs=0.05)
        # On the map: the pixels inside the zone change with the zones layer.
        inside = "(() => { const c = document.getElementById('map'), d = window.devicePixelRatio;" \
                 " const [sx, sy] = window.curio.toScreen(1.7, 2.2);" \
                 " return Array.from(c.getContext('2d').getImageData(sx * d, sy * d, 1, 1).data)" \
                 ".slice(0, 3); })()"
        await b.page.evaluate("() => window.curio.view.dirty = true")
        await b.wait_js("true")
        shown = await b.state(inside)
        await b.page.evaluate("() => document.getElementById('showZones').click()")
        await b.page.wait_for_timeout(200)
        hidden = await b.state(inside)
        await b.page.evaluate("() => document.getElementById('showZones').click()")
        assert shown != hidden and shown[0] > shown[2] + 20, (shown, hidden)  # amber over it
        await b.page.evaluate("() => window.scrollTo(0, 0)")
        await b.shot("zone-saved")

        # A keep-out zone over the rover: the rover's sentence, nothing saved.
        b.allowed.append("status of 400 (Bad Request)")  # the browser logs the refusal
        x, y = kit.truth_xy(app)
        await b.look_at(x, y, 70.0)
        await _draw(b, [(x - 0.7, y - 0.7), (x + 0.7, y - 0.7), (x + 0.7, y + 0.7),
                        (x - 0.7, y + 0.7)])
        await b.page.click("#zSave")
        await b.wait_js("document.querySelector('#zMsg').className.includes('error')")
        refusal = await b.text("#zMsg")
        assert "rover" in refusal.lower() or "home" in refusal.lower(), refusal
        assert len(app.zones.list_zones()["zones"]) == 1
        await b.shot("zone-refused", "#zonesCard")
        await b.page.click("#zCancel")

        # Choose it in the list and delete it.
        await b.page.click(".zPick")
        await b.page.click("#zDelete")
        await b.confirm("Delete the zone", accept=True)
        await b.wait_js("window.curio.Z.zones.length === 0")
        assert app.zones.list_zones()["zones"] == []
        assert b.errors == []


async def test_people_layer_in_a_crowd(tmp_path: Path, viewport: str) -> None:
    """With simulated visitors the page draws the tracked people (orange, with velocity
    arrows) and the visitors' truth; the layer switch hides them. Drives: the crowd
    simulator, the people tracker, the hub's people frames."""
    cfg = kit.make_cfg(tmp_path / "data", "sim.crowd.visitors=10")
    async with kit.running_app(cfg) as (app, _), \
            kit.browser_on(app.web_url or "", viewport) as b:
        await b.wait_js("window.curio.P.truth.length >= 10")  # and the world's scripted walker
        await b.wait_js("window.curio.P.tracks.length > 0", timeout_s=40)
        # Zoomed in on a track (zoomed out, its disc hides under the laser's points).
        track = await b.state("window.curio.P.tracks[0]")
        await b.look_at(track["x"], track["y"], 80.0)
        await b.page.wait_for_timeout(300)
        # The layer's last drawing holds the tracks' discs (read in one go with the canvas).
        await b.wait_js("window.curio.P.drawn.length > 0")
        # Some track's disc shows (not covered by the laser's points or the rover) in a drawing.
        await b.wait_js(
            "(() => { const c = document.getElementById('map').getContext('2d'),"
            " d = window.devicePixelRatio; return window.curio.P.drawn.some(([x, y]) => {"
            " const [r, g, bl] = c.getImageData(x * d, y * d, 1, 1).data;"
            " return r > 200 && g > 80 && g < 200 && r - bl > 60; }); })()", timeout_s=15)
        await b.page.evaluate("() => window.scrollTo(0, 0)")
        await b.shot("people")
        await b.page.evaluate("() => window.curio.fitView()")
        await b.shot("people-overview")
        await b.page.evaluate("() => document.getElementById('showPeople').click()")
        await b.wait_js("window.curio.P.drawn.length === 0")
        assert b.errors == []
