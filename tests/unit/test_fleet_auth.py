"""Signed fleet commands: the rover's own check of signature, target, age, replay and role."""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from curio.fleet.auth import (
    ChainedKeys,
    CommandRefused,
    CommandSigner,
    CommandVerifier,
    FleetKeyError,
    FleetKeyring,
    KeyEntry,
    TokenStoreKeys,
    action_permission,
)

OPERATOR = KeyEntry("fleet", "operator", "s" * 32)
KIOSK = KeyEntry("lobby", "kiosk", "k" * 32)
ADMIN = KeyEntry("boss", "admin", "a" * 32)


class Keys:
    def __init__(self, *entries: KeyEntry) -> None:
        self.entries = {e.name: e for e in entries}

    def key(self, name: str) -> KeyEntry | None:
        return self.entries.get(name)


class Wall:
    def __init__(self, t: float = 1_700_000_000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def verifier(wall: Wall, rover: str = "r1") -> CommandVerifier:
    return CommandVerifier(rover, Keys(OPERATOR, KIOSK, ADMIN), wall, max_age_s=30.0)


def test_a_signed_command_passes_and_names_its_sender() -> None:
    wall = Wall()
    v = verifier(wall).verify(CommandSigner(OPERATOR, wall).sign("r1", {"action": "estop"}))
    assert (v.key, v.role, v.cmd["action"], v.source) == ("fleet", "operator", "estop",
                                                          "fleet:fleet")


@pytest.mark.parametrize("tamper, why", [
    (lambda e: e.pop("sig"), "not signed"),
    (lambda e: e.update(sig=5), "no valid 'sig'"),
    (lambda e: e.update(cmd={"action": "estop", "x": 1}), "bad signature"),
    (lambda e: e.update(key="stranger"), "unknown key"),
    (lambda e: e.update(rover="r2"), "for rover 'r2'"),
    (lambda e: e.update(v=2), "unsupported envelope version"),
    (lambda e: e.update(nonce="zz"), "nonce"),
])
def test_tampered_or_foreign_envelopes_are_refused(tamper, why) -> None:
    wall = Wall()
    env = CommandSigner(OPERATOR, wall).envelope("r1", {"action": "estop"})
    tamper(env)
    with pytest.raises(CommandRefused, match=why):
        verifier(wall).verify(json.dumps(env).encode())


def test_not_json_and_unsigned_plain_commands_are_refused() -> None:
    wall = Wall()
    for payload in (b"\xff\xfe", b"[1, 2]", json.dumps({"action": "estop"}).encode()):
        with pytest.raises(CommandRefused):
            verifier(wall).verify(payload)


def test_a_stale_command_and_a_replay_are_refused() -> None:
    wall = Wall()
    signed = CommandSigner(OPERATOR, wall).sign("r1", {"action": "pause"})
    v = verifier(wall)
    v.verify(signed)
    with pytest.raises(CommandRefused, match="replayed"):
        v.verify(signed)
    wall.t += 31.0
    with pytest.raises(CommandRefused, match="stamped 31 s ago"):
        verifier(wall).verify(signed)


def test_roles_grant_what_the_dashboard_roles_grant() -> None:
    wall = Wall()
    v = verifier(wall)
    assert v.verify(CommandSigner(KIOSK, wall).sign("r1", {"action": "start_tour"})).role == "kiosk"
    for action in ("estop", "goto", "go_home", "pause"):
        with pytest.raises(CommandRefused, match="role kiosk"):
            v.verify(CommandSigner(KIOSK, wall).sign("r1", {"action": action}))
    assert action_permission("release_estop") == "estop"
    assert v.verify(CommandSigner(ADMIN, wall).sign("r1", {"action": "goto"})).may(
        "release_any_estop")


def test_keyring_file_is_private_and_survives_a_reload(tmp_path: Path) -> None:
    path = tmp_path / "fleet_keys.json"
    ring = FleetKeyring(path)
    made = ring.add("fleet", "operator")
    ring.add("lobby", "kiosk", "x" * 20)
    assert os.stat(path).st_mode & 0o077 == 0
    again = FleetKeyring(path)
    assert again.key("FLEET") == made and again.key("lobby").role == "kiosk"
    with pytest.raises(FleetKeyError, match="exists already"):
        again.add("fleet", "admin")
    with pytest.raises(FleetKeyError, match="role 'root'"):
        again.add("x", "root")
    again.revoke("lobby")
    assert FleetKeyring(path).key("lobby") is None


def test_a_corrupt_keyring_is_refused_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "fleet_keys.json"
    path.write_text("{not json")
    with pytest.raises(FleetKeyError, match=str(path)):
        FleetKeyring(path)


def test_dashboard_tokens_can_sign_fleet_commands() -> None:
    store = SimpleNamespace(find=lambda name: SimpleNamespace(name="ops", role="operator",
                                                              token="t" * 32))
    keys = ChainedKeys([Keys(), TokenStoreKeys(store)])
    entry = keys.key("ops")
    assert entry is not None and entry.role == "operator"
    wall = Wall()
    v = CommandVerifier("r1", keys, wall).verify(CommandSigner(entry, wall).sign(
        "r1", {"action": "pause"}))
    assert v.key == "ops"

    def missing(name: str) -> None:
        raise ValueError(name)

    assert TokenStoreKeys(SimpleNamespace(find=missing)).key("x") is None
