"""The fleet's ``dock`` uses the rover's real docking when a dock is fitted, and the status the
manager reads carries the dock, the power model's state of charge and the dashboard's address."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import Config, load_config
from curio.fleet import codec
from curio.fleet.auth import CommandSigner, FleetKeyring, KeyEntry
from curio.fleet.transport import MemoryNetwork, MemoryTransport

pytestmark = [pytest.mark.timeout(300)]

FLEET = KeyEntry("fleet", "operator", "f" * 32)


Rover = tuple[App, SimClock, MemoryTransport, list[dict[str, Any]], list[dict[str, Any]]]


async def started_rover(cfg: Config, keys: tuple[KeyEntry, ...] = (FLEET,)) -> Rover:
    """Rover ``r1`` of ``cfg`` (fleet on) on an in-process link, its keyring holding ``keys``,
    started and run 3 s; the other end of the link, and its statuses and replies as heard."""
    ring = FleetKeyring(cfg.data_path(cfg.fleet.keys_file))
    for k in keys:
        ring.add(k.name, k.role, k.secret)
    net = MemoryNetwork()
    them = MemoryTransport("manager", net)
    clock = SimClock()
    app = App(cfg, clock, web=False, fleet_transport=MemoryTransport("r1", net))
    statuses: list[dict[str, Any]] = []
    replies: list[dict[str, Any]] = []
    them.subscribe("curio/r1/status", lambda s: statuses.append(codec.loads(s.payload)))
    them.subscribe("curio/r1/reply", lambda s: replies.append(codec.loads(s.payload)))
    them.open()
    await app.start()
    await clock.run(until_s=3.0)
    return app, clock, them, statuses, replies


async def _rover(tmp_path: Path, dock: bool) -> Rover:
    cfg = load_config(None, [f'data_dir="{tmp_path}"', "web.enabled=false",
                             f"dock.enabled={'true' if dock else 'false'}",
                             "sim.start=[-0.75, 0.12, 0.15]", "bt.speak=false",
                             "fleet.enabled=true", 'fleet.rover="r1"',
                             'fleet.dashboard_url="http://10.0.0.11:8080/"'])
    app, clock, them, statuses, replies = await started_rover(cfg)
    them.put("curio/r1/cmd", CommandSigner(FLEET, clock.wall_time).sign(
        "r1", {"action": "dock", "request_id": "d1"}))
    return app, clock, them, statuses, replies


async def test_dock_from_the_fleet_drives_the_docker_and_the_status_shows_it(
        tmp_path: Path) -> None:
    app, clock, them, statuses, replies = await _rover(tmp_path, dock=True)
    assert app.docker is not None
    for _ in range(180):  # at most 90 s: staging, the approach on the dock's shape, contact
        await clock.run(until_s=clock.now() + 0.5)
        if app.docker.docked:
            break
    await clock.run(until_s=clock.now() + 2.0)
    them.pump()
    assert next(r for r in replies if r["request_id"] == "d1")["ok"] is True
    assert app.docker.docked and app.world is not None and app.world.docked
    dock_states = [st["dock"]["state"] for st in statuses]
    assert {"staging", "approaching"} & set(dock_states), dock_states
    last = statuses[-1]
    assert last["dock"]["state"] == "docked" and last["dock"]["charging"] is True
    assert 0.0 <= last["soc"] <= 1.0 and last["power_level"] in ("ok", "low", "critical")
    assert last["dashboard"] == "http://10.0.0.11:8080/"
    await app.stop()


async def test_dock_is_refused_without_a_dock_and_the_status_says_none(tmp_path: Path) -> None:
    app, clock, them, statuses, replies = await _rover(tmp_path, dock=False)
    await clock.run(until_s=5.0)
    them.pump()
    (reply,) = [r for r in replies if r["action"] == "dock"]
    assert reply["ok"] is False and "no dock" in reply["reason"]
    assert statuses[-1]["dock"] is None and app.docker is None
    await app.stop()
