"""The shared map pushed from the fleet manager: a rover run by ``curio run``'s map host, over
real Zenoh sessions on the loopback, refuses the map while it drives, takes it once parked (a
new revision in its library, the App rebuilt on it, the pose kept) and then reports the
manager's fingerprint; bad pushes are refused; the manager pushes only to rovers on its map
whose cells differ, again after ``map_resend_s``, and re-reads its map file when it changes."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from curio.commands.host import MapHost
from curio.core.clock import SimClock
from curio.core.config import REPO_ROOT, load_config
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorCommand
from curio.core.topics import OPERATOR, POSE
from curio.estimation.maps import load_map, save_map
from curio.estimation.wiring import map_path
from curio.fleet import codec
from curio.fleet.auth import PERMISSIONS, FleetKeyring, KeyEntry, Verified, action_permission
from curio.fleet.commands import CommandExecutor
from curio.fleet.manager.roster import Roster
from curio.fleet.manager.service import FleetManager
from curio.fleet.maps_sync import MapDistributor, encode_pushed_map
from curio.fleet.zenoh_link import ZenohSettings, ZenohTransport, free_local_endpoint
from curio.maps.control import MapsAccess

pytest.importorskip("zenoh")

FLEET = KeyEntry("fleet", "operator", "f" * 32)
LOBBY = KeyEntry("lobby", "kiosk", "l" * 32)
BLOCK = (slice(60, 66), slice(250, 256))  # cells of a new wall: a crate in the workshop


def _edited_map(tmp: Path, name: str, edit: bool = True) -> tuple[Path, str]:
    """A copy of the default building (with ``edit``, a new block of wall in it) as
    ``tmp/<name>/<name>.yaml``; its path and fingerprint."""
    cfg = load_config(REPO_ROOT / "config.toml", [])
    grid = load_map(map_path(cfg))
    data = grid.data.copy()
    if edit:
        data[BLOCK] = 100
    edited = type(grid)(data, grid.resolution_m, grid.origin, grid.occupied_thresh,
                        grid.free_thresh, name)
    path = save_map(edited, tmp / name / f"{name}.yaml")
    return path, codec.grid_digest(load_map(path).data)


async def _until(clock: SimClock, predicate: Any, timeout_s: float) -> bool:
    return bool(await clock.wait_until(predicate, timeout_s, 0.2))


async def test_a_parked_rover_takes_the_managers_map_and_a_driving_one_waits(
        tmp_path: Path) -> None:
    ep = free_local_endpoint()
    rover_cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path / "rover"}"', "web.enabled=false", "bt.speak=false",
        "maps.enabled=true", "fleet.enabled=true", 'fleet.rover="r1"', 'fleet.mode="client"',
        f'fleet.connect=["{ep}"]'])
    ring = FleetKeyring(rover_cfg.data_path(rover_cfg.fleet.keys_file))
    for k in (FLEET, LOBBY):
        ring.add(k.name, k.role, k.secret)
    clock = SimClock(speed=4.0, epoch_wall_s=1_700_000_000.0)
    host = MapHost(rover_cfg, clock, web=False)
    name = host.active
    shared, same_sha = _edited_map(tmp_path / "manager-maps", name, edit=False)
    mgr_cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path / "manager"}"', f'localization.map_yaml="{shared}"',
        "fleet.manager.map_resend_s=3.0", "fleet.manager.check_period_s=0.5"])
    link = ZenohTransport("manager", ZenohSettings("router", listen=(ep,)))
    manager = FleetManager(mgr_cfg, clock, link, FLEET, expected=["r1"])
    runner = asyncio.create_task(clock.run())
    await manager.start()
    app = await host.start()
    stop = asyncio.Event()
    serve = asyncio.create_task(host.serve(stop))
    try:
        assert await _until(clock, lambda: manager.roster.get("r1").status.get("map")
                            == same_sha, 20.0), "the rover and the manager share the map"
        pose = app.bus.latest(POSE)
        assert pose is not None
        start = pose.pose
        # Driving: a goal a few metres away; then the shared map changes on the manager.
        app.bus.publish(OPERATOR, OperatorCommand(clock.now(), "goto", source="test",
                                                  goal=Pose2D(start.x + 2.0, start.y, 0.0)))
        await clock.sleep(1.0)
        _, sha = _edited_map(tmp_path / "manager-maps", name)
        assert await _until(clock, lambda: manager.map_sha == sha, 5.0)  # read again
        assert await _until(clock, lambda: any(
            e["kind"] == "maps.sent" for e in manager.log), 20.0), manager.log[-5:]
        assert await _until(clock, lambda: any(
            e["kind"] == "maps.refused" for e in manager.log), 10.0), manager.log[-5:]
        refused = next(e for e in manager.log if e["kind"] == "maps.refused")
        assert "busy (it is driving to a goal)" in refused["detail"]["reason"]
        assert host.generation == 1, "the map must not change under a driving rover"
        app.bus.publish(OPERATOR, OperatorCommand(clock.now(), "cancel", source="test"))
        assert await _until(clock, lambda: host.generation == 2, 30.0), manager.log[-5:]
        new_app = host.app
        assert new_app is not None and new_app is not app
        assert host.library.meta(name)["revision"] == 2
        assert len(host.library.revisions(name)) >= 1           # the old one is kept
        grid = host.library.grid(name)
        assert codec.grid_digest(grid.data) == sha
        assert not host.pose_needed                              # same building: pose kept
        assert await _until(clock, lambda: manager.roster.get("r1").status.get("map") == sha,
                            20.0)
        assert not manager.roster.get("r1").status.get("map_differs")
        sent = [e for e in manager.log if e["kind"] == "maps.sent"]
        assert len(sent) >= 2                                   # refused once, then taken
        assert any(e["kind"] == "maps.taken" for e in manager.log)
        await clock.sleep(5.0)
        assert [e for e in manager.log if e["kind"] == "maps.sent"] == sent  # not again
        assert new_app.costmap is not None
        cx, cy = grid.cell_to_world(BLOCK[0].start + 2, BLOCK[1].start + 2)
        assert new_app.costmap.cost_at(cx, cy) >= 254            # the new wall is in the costmap
    finally:
        stop.set()
        await serve
        await manager.stop()
        await host.stop()
        link.close()
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner


def test_the_manager_pushes_its_map_only_where_it_differs(tmp_path: Path) -> None:
    path, sha = _edited_map(tmp_path, "building")
    roster = Roster()
    sent: list[tuple[str, dict[str, Any]]] = []
    notes: list[tuple[str, dict[str, Any]]] = []
    dist = MapDistributor(path, "building", roster, lambda r, c: sent.append((r, c)),
                          lambda k, d: notes.append((k, d)), resend_s=10.0)
    assert dist.sha == sha

    def hear(rover: str, theirs: str, now: float, map_name: str = "building") -> None:
        roster.heard(rover, "status", {"map": theirs, "map_name": map_name}, now)

    hear("a", "old", 100.0)
    hear("b", sha, 100.0)                                  # already has it
    hear("c", "old", 100.0, map_name="other")               # on another map: left alone
    assert dist.check(100.0, 5.0) == ["a"]
    cmd = sent[-1][1]
    assert (cmd["action"], cmd["map"], cmd["sha"]) == ("set_map", "building", sha)
    assert cmd["grid"] == encode_pushed_map(load_map(path))
    assert dist.check(105.0, 5.0) == []                     # not again within resend_s
    hear("a", "old", 111.0)
    assert dist.check(111.0, 5.0) == ["a"]                  # still different: asked again
    assert dist.check(130.0, 5.0) == []                     # offline (not heard since 111)
    hear("a", sha, 131.0)
    assert dist.check(141.0, 5.0) == []                     # took it
    # The file changes: read again, pushed to everybody on the map whose cells differ.
    grid = load_map(path)
    grid.data[BLOCK] = 0
    save_map(grid, path)
    assert not dist.reload() or dist.sha != sha
    assert dist.sha != sha and notes[-1][0] == "maps.changed"
    assert not dist.reload()
    hear("a", sha, 142.0)
    hear("b", sha, 142.0)
    assert dist.check(142.0, 5.0) == ["a", "b"]


async def test_bad_pushes_are_refused_and_change_nothing(tmp_path: Path) -> None:
    """Without a map host (the fleet simulator's rovers), from a kiosk key, for another map,
    with a fingerprint that does not match, unreadable, and with a wall over the rover's
    home."""
    assert action_permission("set_map") == "maps"
    assert "maps" not in PERMISSIONS["kiosk"] and "maps" in PERMISSIONS["operator"]

    cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path}"', "web.enabled=false", "maps.enabled=true"])
    clock = SimClock(epoch_wall_s=1_700_000_000.0)
    host = MapHost(cfg, clock, web=False)
    app = host.build()
    name = host.active
    grid = host.library.grid(name)
    home = app.robot.home
    walled = grid.data.copy()
    row, col = (int(c) for c in grid.world_to_cells(np.array([[home.x, home.y]]))[0])
    walled[row - 3:row + 4, col - 3:col + 4] = 100
    over_home = type(grid)(walled, grid.resolution_m, grid.origin)

    def run(executor: CommandExecutor, role: str, **cmd: Any) -> Any:
        return executor.execute(Verified("k", role, {"action": "set_map", **cmd}))

    reloads: list[str] = []

    class Control:
        def state(self) -> dict[str, Any]:
            return {"busy": None}

        def reload(self, actor: str, why: str) -> str:
            reloads.append(why)
            return "reloading"

    access = MapsAccess(host.library, Control(), name)  # type: ignore[arg-type]
    plain = CommandExecutor(app.bus, clock)
    hosted = CommandExecutor(app.bus, clock, maps=access, home=lambda: home)
    good = {"map": name, "grid": encode_pushed_map(over_home),
            "sha": codec.grid_digest(over_home.data)}
    assert "only a rover run by `curio run`" in run(plain, "operator", **good).reason
    assert "not 'elsewhere'" in run(hosted, "operator", **{**good, "map": "elsewhere"}).reason
    assert "do not match" in run(hosted, "operator", **{**good, "sha": "0" * 16}).reason
    assert "cannot be read" in run(hosted, "operator", **{**good, "grid": "@@@"}).reason
    assert "no free space at the rover's home" in run(hosted, "operator", **good).reason
    assert host.library.meta(name)["revision"] == 1 and reloads == []
