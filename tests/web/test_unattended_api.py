"""The unattended-operation endpoints (curio/web/unattended_api.py) on the aiohttp test client:
battery, dock and home, relocalise and set pose, zones, help and notifications, the socket."""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from aiohttp.test_utils import TestClient

from curio.bt.paths import PathManager
from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import PowerState
from curio.core.topics import INITIAL_POSE, OPERATOR, POWER
from curio.docking.home import HomeDock
from curio.estimation.maps import OccupancyGrid
from curio.help.desk import HelpDesk
from curio.robot import RobotModel
from curio.web.server import create_app
from curio.web.services import WebServices
from curio.web.unattended_api import UnattendedServices
from curio.zones.guard import ZoneGuard
from curio.zones.service import ZoneService
from curio.zones.store import ZoneStore
from tests.unit.test_help import Recorder
from tests.unit.test_unattended_bt import FakeDocker
from tests.web.conftest import TOKEN, make_tokens

AUTH = {"Authorization": f"Bearer {TOKEN}"}
SQUARE = [[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]]


@dataclass
class Rig:
    client: TestClient
    bus: Bus
    home: HomeDock
    docker: FakeDocker | None
    notes: Recorder
    clock: SimClock


async def _rig(aiohttp_client: Any, cfg: Config, bus: Bus, tmp_path: Path,
               docker: FakeDocker | None = None) -> Rig:
    clock = SimClock()
    robot = RobotModel.from_config(cfg.robot)
    grid = OccupancyGrid(np.zeros((100, 100), dtype=np.int8), 0.05, Pose2D(), name="box")
    home = HomeDock(PathManager(cfg.bt.paths, None), 0.7)
    zones = ZoneService(cfg, bus, clock, ZoneStore(tmp_path / "box.json", "box", 0.37), grid,
                        ZoneGuard(robot, cfg.zones), home=home.pose)
    notes = Recorder()
    desk = HelpDesk(cfg, bus, clock, notifier=notes)  # type: ignore[arg-type]

    def placement(x: float, y: float) -> str:
        return "it is outside the map" if x > 5.0 else ""

    extra = UnattendedServices(home, docker, zones, desk, placement)
    app = create_app(WebServices(cfg=cfg, clock=clock, bus=bus,
                                 tokens=make_tokens(tmp_path / "tokens.json"), robot=robot,
                                 unattended=extra))
    return Rig(await aiohttp_client(app), bus, home, docker, notes, clock)


@pytest.fixture
def rig(aiohttp_client: Any, cfg: Config, bus: Bus, tmp_path: Path) -> Any:
    async def make(docker: FakeDocker | None = None) -> Rig:
        return await _rig(aiohttp_client, cfg, bus, tmp_path, docker)
    return make


async def test_power_and_help_are_readable(rig: Any) -> None:
    r = await rig()
    assert (await r.client.get("/api/power")).status == 404
    r.bus.publish(POWER, PowerState(1.0, 7.4, 7.38, 0.6, 3600.0, 3000.0, None, False, "ok"))
    body = await (await r.client.get("/api/power")).json()
    assert body["soc"] == 0.6 and body["time_left_s"] == 3600.0 and body["level"] == "ok"
    help_state = await (await r.client.get("/api/help")).json()
    assert help_state["active"] is False


async def test_zones_crud_needs_the_token_and_explains_refusals(rig: Any) -> None:
    r = await rig()
    zone = {"name": "Stairs", "kind": "keepout", "polygon": SQUARE}
    assert (await r.client.post("/api/zones", json=zone)).status == 401
    bad = await r.client.post("/api/zones", json={**zone, "polygon": SQUARE[:2]},
                              headers=AUTH)
    assert bad.status == 400 and "3 to 200 points" in (await bad.json())["error"]
    made = await r.client.post("/api/zones", json=zone, headers=AUTH)
    assert made.status == 201 and (await made.json())["id"] == 1
    listed = await (await r.client.get("/api/zones")).json()
    assert listed["map"] == "box" and listed["revision"] == 1
    patched = await r.client.patch("/api/zones/1", json={"kind": "speed",
                                                         "speed_limit_mps": 0.1,
                                                         "revision": 1}, headers=AUTH)
    assert patched.status == 200 and (await patched.json())["speed_limit_mps"] == 0.1
    stale = await r.client.delete("/api/zones/1?revision=1", headers=AUTH)
    assert stale.status == 400 and "changed meanwhile" in (await stale.json())["error"]
    files = await (await r.client.post("/api/zones/export", headers=AUTH)).json()
    assert any(f.endswith("box_speed.yaml") for f in files["files"])
    assert (await r.client.delete("/api/zones/1?revision=2", headers=AUTH)).status == 200
    assert (await r.client.delete("/api/zones/x", headers=AUTH)).status == 400


async def test_relocalise_and_set_pose_publish_the_initial_pose(rig: Any) -> None:
    r = await rig()
    sub = r.bus.subscribe(INITIAL_POSE)
    assert (await r.client.post("/api/relocalise", headers=AUTH)).status == 202
    resp = await r.client.post("/api/pose", json={"x_m": 1.0, "y_m": 2.0, "yaw_rad": 0.5,
                                                  "std_xy_m": 0.1}, headers=AUTH)
    assert resp.status == 202
    search, pose = sub.drain()
    assert math.sqrt(search.covariance[0]) == 1000.0
    assert pose.pose == Pose2D(1.0, 2.0, 0.5) and pose.covariance[0] == pytest.approx(0.01)
    assert pose.covariance[8] == pytest.approx(0.04)
    bad = await r.client.post("/api/pose", json={"x_m": 1, "y_m": 2, "std_xy_m": -1},
                              headers=AUTH)
    assert bad.status == 400 and "std_xy_m" in (await bad.json())["error"]


async def test_home_dock_and_undock(rig: Any) -> None:
    r = await rig()
    assert (await r.client.post("/api/dock", headers=AUTH)).status == 409  # no dock fitted
    moved = await r.client.put("/api/home", json={"x_m": 2.0, "y_m": 1.0, "yaw_rad": 0.3},
                               headers=AUTH)
    assert moved.status == 200 and r.home.pose() == Pose2D(2.0, 1.0, 0.3)
    out = await r.client.put("/api/home", json={"x_m": 9.0, "y_m": 1.0}, headers=AUTH)
    assert out.status == 400 and "outside the map" in (await out.json())["error"]
    docked = await rig(FakeDocker("docked"))
    sub = docked.bus.subscribe(OPERATOR)
    assert (await docked.client.post("/api/dock", headers=AUTH)).status == 202
    assert [c.action for c in sub.drain()] == ["go_home"]
    assert (await docked.client.post("/api/undock", headers=AUTH)).status == 202
    assert docked.docker is not None and docked.docker.state == "undocking"
    state = await (await docked.client.get("/api/dock")).json()
    assert state["enabled"] is True and state["home"] == [0.0, 0.0, 0.0]
    assert state["staging"] == [-0.7, 0.0, 0.0]


async def test_notification_test_and_the_socket(rig: Any) -> None:
    r = await rig()
    resp = await r.client.post("/api/notify/test", headers=AUTH)
    assert resp.status == 202 and "no channel" in (await resp.json())["note"]
    assert r.notes.notes[-1].kind == "notify.test"
    ws = await r.client.ws_connect("/api/unattended/ws")
    for _ in range(5):
        await asyncio.sleep(0)  # noqa: TID251 - let the handler subscribe
    r.bus.publish(POWER, PowerState(2.0, 7.0, 7.0, 0.3))
    for _ in range(3):  # the socket pushes on the (simulated) clock's 0.5 s tick
        await r.clock.advance(0.5)
    seen = {}
    while "power" not in seen:  # the latched help state comes too
        msg = await asyncio.wait_for(ws.receive_json(), 5.0)
        seen[msg["t"]] = msg["msg"]
    assert seen["power"]["soc"] == 0.3
    await ws.close()
