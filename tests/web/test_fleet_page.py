"""End-to-end on the fleet view (Debian's Chromium, desktop 1280×800 and phone 390×844): the
fleet manager serves the page built from the dashboard's page kit; three rovers speak to it
over an in-process link exactly as their bridges do (status, pose, plan, events). The page
shows every rover on the shared map with state, battery, tour and alerts and a link to each
rover's dashboard; the manager pushes its zones to a rover whose zones differ; with the
token, Pause reaches the rover as a signed command, a tour is dispatched to the best rover,
and STOP ALL e-stops every rover. Screenshots in ``artifacts/screenshots/``
(``<viewport>-fleet*.png``)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from curio.core.clock import RealClock
from curio.core.config import REPO_ROOT, load_config
from curio.fleet import codec
from curio.fleet.auth import CommandVerifier, KeyEntry
from curio.fleet.manager.service import FleetManager
from curio.fleet.manager.web import FleetWeb
from curio.fleet.transport import MemoryNetwork, MemoryTransport
from curio.tours.model import tour_from_json
from curio.zones.store import ZoneStore
from curio.zones.wiring import zone_file
from tests.web import browser_kit as kit

pytestmark = [pytest.mark.browser, pytest.mark.timeout(240)]

KEY = KeyEntry("fleet", "operator", "k" * 32)
TOKEN = "fleet-page-test-token-0123456789"
DOCK = {"state": "docked", "charging": True, "attempt": 1, "detail": ""}
ROVERS: dict[str, dict[str, Any]] = {
    "r1": {"state": "moving", "text": "Tour 'Highlights': to the Workshop", "ready": False,
           "map": "feedfeedfeedfeed", "map_name": "annex",
           "tour": 1, "tour_name": "Highlights", "tour_phase": "moving", "stop": 1, "stops": 3,
           "battery_v": 7.9, "soc": 0.74, "power_level": "ok", "dock": None,
           "traffic": "yield", "pose": (2.0, 1.0, 0.0),
           "plan": [[2.0, 1.0], [4.0, 1.0], [6.0, 2.5], [8.0, 2.5]]},
    "r2": {"state": "docked", "text": "Charging (63 %)", "ready": True, "battery_v": 7.5,
           "soc": 0.63, "charging": True, "power_level": "ok", "dock": DOCK,
           "zones": {"map": "curio_building", "digest": "not-the-managers", "count": 0},
           "traffic": "clear", "pose": (-4.0, -2.0, 1.57), "plan": []},
    "r3": {"state": "idle", "text": "Idle", "ready": True, "battery_v": 6.9, "soc": 0.18,
           "power_level": "low", "dock": None, "traffic": "clear", "pose": (10.0, 8.0, 3.1),
           "plan": [], "map": "0123456789abcdef", "map_name": "curio_building"},
}
TOUR = {"id": 1, "name": "Highlights", "revision": 1, "stops": [
    {"name": "Entrance", "x_m": 0.0, "y_m": 0.0, "message": "Welcome"},
    {"name": "Workshop", "x_m": 4.0, "y_m": 1.0, "message": "Tools"}]}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class OneKey:
    """The rover's keyring: the manager's key."""

    def key(self, name: str) -> KeyEntry | None:
        return KEY if name == KEY.name else None


class FakeRover:
    """A rover's link publishing what its bridge would, and the commands it received."""

    def __init__(self, name: str, net: MemoryNetwork, clock: RealClock) -> None:
        self.name, self.clock = name, clock
        self.link = MemoryTransport(name, net)
        self.verifier = CommandVerifier(name, OneKey(), clock.wall_time, 30.0)
        self.commands: list[dict[str, Any]] = []
        self.link.subscribe(f"curio/{name}/cmd", lambda s: self.commands.append(
            self.verifier.verify(s.payload).cmd))
        self.link.declare_token(f"curio/{name}/alive")
        self.link.open()
        self.seq = 0

    def status(self, **over: Any) -> None:
        spec = {**ROVERS[self.name], **over}
        x, y, yaw = spec.pop("pose")
        plan = spec.pop("plan")
        t = self.clock.wall_time()
        body = {"t": t, "rover": self.name, "estop": False, "loc": "ok", "goal": bool(plan),
                "dashboard": f"http://{self.name}.local:8080/", "map": "", **spec}
        self.link.put(f"curio/{self.name}/status", codec.dumps(body))
        self.link.put(f"curio/{self.name}/pose", codec.dumps({"t": t, "x": x, "y": y,
                                                               "yaw": yaw}))
        self.link.put(f"curio/{self.name}/plan", codec.dumps({"t": t, "pts": plan}))

    def event(self, kind: str, **detail: Any) -> None:
        self.seq += 1
        self.link.put(f"curio/{self.name}/events", codec.dumps({
            "t": self.clock.wall_time(), "seq": self.seq, "kind": kind, "detail": detail}))


@contextlib.asynccontextmanager
async def fleet(tmp_path: Path) -> AsyncIterator[tuple[str, FleetManager, dict[str, FakeRover]]]:
    cfg = load_config(REPO_ROOT / "config.toml", [f'data_dir="{tmp_path}"'])
    clock = RealClock()
    net = MemoryNetwork()
    link = MemoryTransport("manager", net)
    ZoneStore(zone_file(cfg, "curio_building"), "curio_building", 0.5).add(
        "Stairs", "keepout", [[10.0, 8.0], [11.0, 8.0], [11.0, 9.0], [10.0, 9.0]])
    manager = FleetManager(cfg, clock, link, KEY)
    manager.tours.upsert(tour_from_json(TOUR), actor="test")
    port = free_port()
    manager.web = FleetWeb(manager, "127.0.0.1", port, TOKEN)
    await manager.start()
    rovers = {name: FakeRover(name, net, clock) for name in ROVERS}

    async def speak() -> None:
        async for _ in clock.every(0.5):
            for r in rovers.values():
                r.status()
                r.link.pump()

    rovers["r1"].event("help.requested", reason="blocked",
                       message="Something blocks the corridor.")
    talker = asyncio.create_task(speak())
    try:
        yield f"http://127.0.0.1:{port}/", manager, rovers
    finally:
        talker.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await talker
        await manager.stop()


async def test_the_fleet_view(tmp_path: Path, viewport: str) -> None:
    async with fleet(tmp_path) as (url, _manager, rovers), kit.chromium() as browser:
        # (r1 is on another map, r3 on an older revision of the shared one.)
        b = await kit.open_page(browser, url, viewport, connected=False)
        await b.wait_js("document.querySelectorAll('.rover').length === 3 && "
                        "window.curio.fleet.img !== null")
        await b.wait_js("document.querySelector('.rover[data-name=r1] .alerts') !== null")
        cards = await b.text("#rovers")
        assert "Tour: Highlights · stop 2 of 3" in cards
        assert "74 % · 7.90 V" in cards and "on the dock" in cards and "giving way" in cards
        assert "help.requested: Something blocks the corridor." in cards
        link = await b.page.get_attribute(".rover[data-name=r2] a.dash", "href")
        assert link == "http://r2.local:8080/"
        assert "low" in (await b.page.get_attribute(".rover[data-name=r3] .battery", "class")
                         or "")
        # r2's zones differ from the manager's: the page says so and the zones are sent.
        assert "zones being sent" in await b.text(".rover[data-name=r2] .roverTop")
        rovers["r2"].link.pump()
        assert [c["action"] for c in rovers["r2"].commands] == ["set_zones"]
        assert rovers["r2"].commands[0]["zones"][0]["name"] == "Stairs"
        # r3 runs an older revision of the shared map: it is sent; r1 is on another map.
        assert "other map" in await b.text(".rover[data-name=r1] .roverTop")
        assert "map being sent" in await b.text(".rover[data-name=r3] .roverTop")
        r3 = rovers["r3"]
        r3.link.pump()
        (push,) = [c for c in r3.commands if c["action"] == "set_map"]
        assert push["map"] == "curio_building" and push["sha"] == _manager.map_sha
        r3.link.put("curio/r3/reply", codec.dumps({
            "t": r3.clock.wall_time(), "request_id": push["request_id"], "ok": False,
            "reason": "busy (it is driving to a goal): the map is taken when the rover is "
                      "parked"}))
        await b.wait_js("document.querySelector('.rover[data-name=r3] .roverTop').textContent"
                        ".includes('map update waiting')")
        title = await b.page.get_attribute(".rover[data-name=r3] .pill.map", "title")
        assert title is not None and "driving to a goal" in title
        # View only without the token: nothing can be sent.
        assert await b.state("document.querySelector('.roverActions button').disabled")
        assert await b.state("document.getElementById('estop').disabled")
        # The shared map fills its card (it was drawn 160 px wide when the Maps page's
        # .mapCard grid also styled the fleet's card).
        assert await b.state("(() => { const c = document.getElementById('fleetMap'); "
                             "return c.clientWidth >= 0.9 * c.parentElement.clientWidth "
                             "&& c.clientWidth > 300; })()")
        # Every rover is drawn on the map in its colour (the pixels are there).
        assert await b.state(PIXELS_OF_ROVERS) == 3
        await b.shot("fleet")
        await b.shot("fleet-rovers", "#rovers")

        # With the manager's token: Pause reaches r1 signed; the tour goes to the best rover.
        b = await kit.open_page(browser, url + f"?token={TOKEN}", viewport, connected=False)
        await b.wait_js("document.querySelectorAll('.rover').length === 3 && "
                        "!document.querySelector('.rover[data-name=r1] .roverActions button')"
                        ".disabled")
        await b.page.click(".rover[data-name=r1] .roverActions button:text('Pause')")
        await b.wait_js("document.getElementById('fleetMsg').textContent.includes('sent to r1')")
        clock = rovers["r1"].clock
        async for _ in clock.every(0.1):
            rovers["r1"].link.pump()
            if rovers["r1"].commands or len(b.errors) > 0:
                break
        assert [c["action"] for c in rovers["r1"].commands] == ["pause"]
        assert await b.text(".rover[data-name=r2] .roverActions") == "PauseResumeDock"
        await b.page.click("#tours button")
        await b.wait_js("document.querySelector('#jobs tbody tr.sent') !== null", 10)
        assert await b.text("#jobs tbody tr.sent td:nth-child(4)") == "r2"  # r3: 18 % charge
        await b.page.click("#estop")
        await b.wait_js("document.getElementById('toast').textContent.includes('3 rovers')")
        await b.shot("fleet-operator", "#tours")
        assert b.errors == []


# How many rovers' colours are on the map canvas (each rover's disc is drawn in its colour).
PIXELS_OF_ROVERS = """(() => {
    const c = document.getElementById('fleetMap'), d = c.getContext('2d').getImageData(0, 0,
        c.width, c.height).data;
    const want = [[37, 99, 235], [219, 39, 119], [5, 150, 105]];
    let found = 0;
    for (const [r, g, bl] of want) {
        for (let i = 0; i < d.length; i += 4)
            if (d[i] === r && d[i + 1] === g && d[i + 2] === bl) { found++; break; }
    }
    return found;
})()"""
