"""Commands from the network: only signed ones with the right role move the rover, and they go
through the same operator channel and safety stage as the dashboard's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.topics import ESTOP, EVENTS, OPERATOR
from curio.fleet import codec
from curio.fleet.auth import CommandSigner, FleetKeyring, KeyEntry
from curio.fleet.transport import MemoryNetwork, MemoryTransport, Transport
from curio.fleet.zenoh_link import ZenohSettings, ZenohTransport, free_local_endpoint

FLEET = KeyEntry("fleet", "operator", "f" * 32)
LOBBY = KeyEntry("lobby", "kiosk", "l" * 32)
STRANGER = KeyEntry("stranger", "admin", "s" * 32)


def links(kind: str) -> tuple[Transport, Transport]:
    if kind == "memory":
        net = MemoryNetwork()
        return MemoryTransport("r1", net), MemoryTransport("them", net)
    pytest.importorskip("zenoh")
    ep = free_local_endpoint()
    return (ZenohTransport("r1", ZenohSettings("client", connect=(ep,))),
            ZenohTransport("them", ZenohSettings("router", listen=(ep,))))


@pytest.mark.parametrize("kind", ["memory", "zenoh"])
async def test_unsigned_foreign_and_underprivileged_commands_are_refused(
        cfg: Config, tmp_path: Path, kind: str) -> None:
    cfg = cfg.model_copy(update={"fleet": cfg.fleet.model_copy(update={
        "enabled": True, "rover": "r1"})})
    ring = FleetKeyring(cfg.data_path(cfg.fleet.keys_file))
    for k in (FLEET, LOBBY):
        ring.add(k.name, k.role, k.secret)
    rover_link, them = links(kind)
    clock = SimClock()
    app = App(cfg, clock, fleet_transport=rover_link)
    replies: list[dict] = []
    them.subscribe("curio/r1/reply", lambda s: replies.append(codec.loads(s.payload)))
    ops = app.bus.subscribe(OPERATOR)
    events = app.bus.subscribe(EVENTS)
    them.open()
    await app.start()
    await clock.run(until_s=2.0)

    def send(payload: bytes) -> None:
        them.put("curio/r1/cmd", payload)

    wall = clock.wall_time
    estop = {"action": "estop", "request_id": "x"}
    valid = CommandSigner(FLEET, wall).sign("r1", {"action": "pause", "request_id": "p"})
    send(json.dumps(estop).encode())                                   # unsigned
    send(CommandSigner(STRANGER, wall).sign("r1", estop))              # unknown key
    send(CommandSigner(LOBBY, wall).sign("r1", estop))                 # kiosk may not
    send(CommandSigner(FLEET, wall).sign("r2", estop))                 # another rover's
    env = CommandSigner(FLEET, wall).envelope("r1", estop)
    env["cmd"]["action"] = "go_home"                                   # tampered
    send(json.dumps(env).encode())
    send(valid)
    send(valid)                                                        # replayed
    await clock.run(until_s=3.0)
    them.pump()
    assert [c.action for c in ops.drain()] == ["pause"]
    latest = app.bus.latest(ESTOP)
    assert latest is None or not latest.engaged
    refused = [e for e in events.drain() if e.kind == "fleet.command_refused"]
    reasons = " | ".join(e.detail["reason"] for e in refused)
    for why in ("the command is not signed", "unknown key 'stranger'",
                "role kiosk) may not estop", "for rover 'r2'", "bad signature", "replayed"):
        assert why in reasons
    assert len(refused) == 6 and sum(1 for r in replies if not r["ok"]) == 6

    # A signed e-stop from an operator key latches through the safety stage; a kiosk key may
    # not release it, the key that set it may.
    send(CommandSigner(FLEET, wall).sign("r1", {"action": "estop", "request_id": "e1"}))
    await clock.run(until_s=4.0)
    latest = app.bus.latest(ESTOP)
    assert latest is not None and latest.engaged and latest.source == "fleet:fleet"
    send(CommandSigner(LOBBY, wall).sign("r1", {"action": "release_estop"}))
    await clock.run(until_s=5.0)
    assert app.bus.latest(ESTOP).engaged
    send(CommandSigner(FLEET, wall).sign("r1", {"action": "release_estop", "request_id": "e2"}))
    await clock.run(until_s=6.0)
    assert not app.bus.latest(ESTOP).engaged
    await app.stop()
    them.close()


async def test_dashboard_tokens_sign_fleet_commands_with_their_roles(cfg: Config) -> None:
    cfg = cfg.model_copy(update={"fleet": cfg.fleet.model_copy(update={
        "enabled": True, "rover": "r1"})})
    rover_link, them = links("memory")
    clock = SimClock()
    app = App(cfg, clock, fleet_transport=rover_link)
    admin = app.tokens.first_admin()
    kiosk = app.tokens.create("lobby screen", "kiosk")
    assert admin is not None
    them.open()
    await app.start()
    await clock.run(until_s=2.0)
    wall = clock.wall_time
    for entry in (kiosk, admin):
        key = KeyEntry(entry.name, entry.role, entry.token)
        them.put("curio/r1/cmd", CommandSigner(key, wall).sign("r1", {"action": "estop"}))
        await clock.run(until_s=clock.now() + 1.0)
        latest = app.bus.latest(ESTOP)
        engaged = latest is not None and latest.engaged
        assert engaged is (entry.role == "admin")
    assert app.bus.latest(ESTOP).source == f"fleet:{admin.name}"
    await app.stop()
