"""Signed fleet commands: every command from the network carries an HMAC signature made with
a named key, and the rover checks it with its *own* keys and roles before anything moves.

**The envelope** (JSON): ``{"v": 1, "rover": <target>, "key": <key name>, "ts": <UNIX s>,
"nonce": <16 hex>, "cmd": {...}, "sig": <hex>}``. The signature is HMAC-SHA256 over the
envelope without ``sig`` (keys sorted, no spaces, ASCII), keyed with SHA-256 of
``"curio-fleet-command-v1\\0" + secret`` (the stored secret is never the MAC key itself).

**The check** (:class:`CommandVerifier`, in this order, each refusal a sentence): the envelope
is well formed; it is addressed to *this* rover (a command for another rover cannot be
replayed here); the key is one this rover knows; the signature matches (constant-time); the
stamp is within ``max_age_s`` of the rover's clock; the nonce was not seen (replay); the key's
role may do the action. A refused command changes nothing; the bridge answers with the reason
and logs ``fleet.command_refused``.

**Roles** are the dashboard's (issue 20): ``kiosk`` may start and stop tours; ``operator`` may
also send goals, pause, go home, use the e-stop, push tour definitions, a map and its zones;
``admin`` may also
release an e-stop that somebody else set. :data:`PERMISSIONS` and :func:`action_permission`
mirror ``curio/web/tokens.py`` and ``curio/web/control.py`` on the dashboard branch and are kept
here so that this module stands alone; a fleet command never gets more than the dashboard's
operator role grants.

**Keys** come from a :class:`KeyLookup`: the fleet's own keyring file
(:class:`FleetKeyring`, ``<data_dir>/fleet_keys.json``, 0600) and — once the dashboard's
named tokens are merged — its token store through :class:`TokenStoreKeys` (a token's secret
then signs fleet commands under the token's name and role). :class:`ChainedKeys` asks each in
turn.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import os
import re
import secrets
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_text, modified_ns

__all__ = [
    "PERMISSIONS",
    "ChainedKeys",
    "CommandRefused",
    "CommandSigner",
    "CommandVerifier",
    "FleetKeyError",
    "FleetKeyring",
    "KeyEntry",
    "KeyLookup",
    "TokenStoreKeys",
    "Verified",
    "action_permission",
]

log = logging.getLogger("curio.fleet.auth")

ENVELOPE_VERSION = 1
_MAC_CONTEXT = b"curio-fleet-command-v1\0"
ROLES: tuple[str, ...] = ("kiosk", "operator", "admin")
PERMISSIONS: dict[str, frozenset[str]] = {
    "viewer": frozenset(),
    "kiosk": frozenset({"tour"}),
    "operator": frozenset({"tour", "estop", "command", "zones", "maps"}),
    "admin": frozenset({"tour", "estop", "command", "zones", "maps", "release_any_estop"}),
}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9 ._@-]{0,31}$")
_HEX16 = re.compile(r"^[0-9a-f]{16,64}$")


def action_permission(action: str) -> str:
    """The permission a fleet action needs (the dashboard's rule)."""
    if action in ("estop", "release_estop"):
        return "estop"
    if action in ("start_tour", "stop_tour"):
        return "tour"
    if action == "set_zones":
        return "zones"
    if action == "set_map":
        return "maps"
    return "command"


class CommandRefused(Exception):
    """A command that must not run; the message says why (for the sender and the log)."""


class FleetKeyError(SetupError, ValueError):
    """A key-management request that cannot be done (bad name, role, unreadable file)."""


@dataclass(frozen=True, slots=True)
class KeyEntry:
    """A named key: who signs with it, the role it grants and the shared secret."""

    name: str
    role: str
    secret: str

    def mac_key(self) -> bytes:
        """The HMAC key derived from the secret."""
        return hashlib.sha256(_MAC_CONTEXT + self.secret.encode("utf-8")).digest()


class KeyLookup(Protocol):
    """Where a rover finds the key a command names."""

    def key(self, name: str) -> KeyEntry | None:
        """The key called ``name``, or None."""
        ...


def _canonical(envelope: dict[str, Any]) -> bytes:
    body = {k: v for k, v in envelope.items() if k != "sig"}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()


class CommandSigner:
    """Signs commands with one key (the fleet manager, ``curio fleet send``).

    Args:
        key: the signing key.
        wall_time: returns UNIX seconds (the injected clock's ``wall_time``).
    """

    def __init__(self, key: KeyEntry, wall_time: Callable[[], float]) -> None:
        self.key = key
        self.wall_time = wall_time

    def envelope(self, rover: str, cmd: dict[str, Any]) -> dict[str, Any]:
        """The signed envelope of ``cmd`` for ``rover``."""
        env: dict[str, Any] = {"v": ENVELOPE_VERSION, "rover": rover, "key": self.key.name,
                               "ts": round(self.wall_time(), 3),
                               "nonce": secrets.token_hex(8), "cmd": cmd}
        env["sig"] = hmac.new(self.key.mac_key(), _canonical(env), hashlib.sha256).hexdigest()
        return env

    def sign(self, rover: str, cmd: dict[str, Any]) -> bytes:
        """The signed envelope as payload bytes."""
        return json.dumps(self.envelope(rover, cmd), separators=(",", ":")).encode()


@dataclass(frozen=True)
class Verified:
    """A command that passed every check: who sent it (key name, role) and what it asks."""

    key: str
    role: str
    cmd: dict[str, Any]

    def may(self, permission: str) -> bool:
        """Whether the sender's role has ``permission``."""
        return permission in PERMISSIONS.get(self.role, frozenset())

    @property
    def source(self) -> str:
        """The command source that names the sender on the rover (``fleet:<key>``)."""
        return f"fleet:{self.key}"


class CommandVerifier:
    """Checks signed envelopes for one rover (see the module docstring).

    Args:
        rover: this rover's name.
        keys: where its keys are looked up.
        wall_time: the rover's UNIX time (injected clock).
        max_age_s: how far a command's stamp may be from the rover's clock.
    """

    def __init__(self, rover: str, keys: KeyLookup, wall_time: Callable[[], float],
                 max_age_s: float = 30.0) -> None:
        self.rover = rover
        self.keys = keys
        self.wall_time = wall_time
        self.max_age_s = max_age_s
        self._nonces: OrderedDict[str, float] = OrderedDict()

    def verify(self, payload: bytes | dict[str, Any]) -> Verified:
        """The verified command in ``payload``.

        Raises:
            CommandRefused: the first check that fails, as a sentence.
        """
        env = self._parse(payload)
        if env["rover"] != self.rover:
            raise CommandRefused(f"the command is for rover {env['rover']!r}, this is "
                                 f"{self.rover!r}")
        key = self.keys.key(env["key"])
        if key is None:
            raise CommandRefused(f"unknown key {env['key']!r}: this rover does not know it")
        expected = hmac.new(key.mac_key(), _canonical(env), hashlib.sha256).hexdigest()
        if not hmac.compare_digest(expected, env["sig"]):
            raise CommandRefused(f"bad signature for key {key.name!r}")
        now = self.wall_time()
        age = now - float(env["ts"])
        if abs(age) > self.max_age_s:
            when = f"{age:.0f} s ago" if age > 0 else f"{-age:.0f} s in the future"
            raise CommandRefused(f"the command was stamped {when} by this rover's clock (at "
                                 f"most {self.max_age_s:g} s either way: stale, replayed, or "
                                 "the clocks disagree)")
        self._expire(now)
        if env["nonce"] in self._nonces:
            raise CommandRefused("the command was already received (replayed nonce)")
        self._nonces[env["nonce"]] = now
        cmd = env["cmd"]
        action = str(cmd.get("action", ""))
        needed = action_permission(action)
        verified = Verified(key.name, key.role, cmd)
        if not verified.may(needed):
            raise CommandRefused(f"the key {key.name!r} (role {key.role}) may not {action}")
        return verified

    def _expire(self, now: float) -> None:
        while self._nonces:
            nonce, seen = next(iter(self._nonces.items()))
            if now - seen <= 2.0 * self.max_age_s and len(self._nonces) < 100_000:
                break
            self._nonces.pop(nonce)

    @staticmethod
    def _parse(payload: bytes | dict[str, Any]) -> dict[str, Any]:
        if isinstance(payload, dict):
            env = payload
        else:
            try:
                env = json.loads(payload.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                raise CommandRefused("the command is not a signed JSON envelope") from None
        if not isinstance(env, dict):
            raise CommandRefused("the command is not a signed JSON envelope")
        if "sig" not in env:
            raise CommandRefused("the command is not signed: every command from the network "
                                 "must carry a signature made with a key this rover knows")
        if env.get("v") != ENVELOPE_VERSION:
            raise CommandRefused(f"unsupported envelope version {env.get('v')!r} "
                                 f"(this rover speaks {ENVELOPE_VERSION})")
        for field, kind in (("rover", str), ("key", str), ("nonce", str), ("sig", str),
                            ("cmd", dict)):
            if not isinstance(env.get(field), kind):
                raise CommandRefused(f"the command has no valid {field!r}: unsigned or "
                                     "malformed")
        ts = env.get("ts")
        if isinstance(ts, bool) or not isinstance(ts, int | float):
            raise CommandRefused("the command has no valid 'ts'")
        if not _HEX16.match(env["nonce"]):
            raise CommandRefused("the command's nonce is not 16-64 hex digits")
        return env


class FleetKeyring:
    """The fleet's named keys in one JSON file (0600, written atomically).

    The file is ``{"version": 1, "keys": [{"name", "role", "secret"}]}``. A missing file is an
    empty keyring. ``curio fleet key create|list|revoke`` edits it.

    Raises:
        FleetKeyError: the file exists but is not a keyring (naming the file).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._keys: dict[str, KeyEntry] = {}
        self._mtime_ns: int | None = None
        self.load()

    def load(self) -> None:
        """(Re)read the file."""
        if not self.path.exists():
            self._keys, self._mtime_ns = {}, None
            return
        try:
            stat = self.path.stat()
            data = json.loads(self.path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or data.get("version") != 1:
                raise ValueError("not a version-1 fleet keyring")
            keys = {}
            for item in data["keys"]:
                entry = KeyEntry(_check_name(str(item["name"])), _check_role(str(item["role"])),
                                 str(item["secret"]))
                if len(entry.secret) < 16:
                    raise ValueError(f"the secret of {entry.name!r} is under 16 characters")
                keys[entry.name.lower()] = entry
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise FleetKeyError(f"the fleet keyring {self.path} cannot be read ({exc}); fix it or "
                            "move it away") from None
        if stat.st_mode & 0o077:
            os.chmod(self.path, 0o600)
        self._keys, self._mtime_ns = keys, stat.st_mtime_ns

    def reload_if_changed(self) -> bool:
        """Re-read the file if it changed (``curio fleet key`` in another process)."""
        mtime = modified_ns(self.path)
        if mtime == self._mtime_ns:
            return False
        try:
            self.load()
        except FleetKeyError as exc:
            log.error("%s; keeping the keys read before", exc)
            self._mtime_ns = mtime
            return False
        return True

    def key(self, name: str) -> KeyEntry | None:
        """The key called ``name`` (case-insensitive), or None."""
        return self._keys.get(name.strip().lower())

    def entries(self) -> list[KeyEntry]:
        """Every key."""
        return list(self._keys.values())

    def _save(self) -> None:
        body = {"version": 1, "keys": [{"name": k.name, "role": k.role, "secret": k.secret}
                                       for k in self._keys.values()]}
        atomic_write_text(self.path, json.dumps(body, indent=2) + "\n", private=True)
        self._mtime_ns = self.path.stat().st_mtime_ns

    def add(self, name: str, role: str, secret: str | None = None) -> KeyEntry:
        """Add a key (a new random secret unless one is given, e.g. the manager's, copied
        to a rover).

        Raises:
            FleetKeyError: the name is taken or not allowed, the role unknown, the secret short.
        """
        entry = KeyEntry(_check_name(name), _check_role(role), secret or secrets.token_urlsafe(24))
        if len(entry.secret) < 16:
            raise FleetKeyError("a fleet key's secret needs at least 16 characters")
        if entry.name.lower() in self._keys:
            raise FleetKeyError(f"a fleet key named {entry.name!r} exists already; revoke it first")
        self._keys[entry.name.lower()] = entry
        self._save()
        return entry

    def revoke(self, name: str) -> KeyEntry:
        """Delete the key called ``name``.

        Raises:
            FleetKeyError: there is none (listing the names there are).
        """
        entry = self._keys.pop(name.strip().lower(), None)
        if entry is None:
            names = ", ".join(k.name for k in self._keys.values()) or "none"
            raise FleetKeyError(f"there is no fleet key named {name!r}; keys: {names}")
        self._save()
        return entry


def _check_name(name: str) -> str:
    clean = " ".join(name.split())
    if not _NAME.match(clean):
        raise FleetKeyError(f"key name {name!r} is not allowed: use 1-32 letters, digits, spaces "
                        "or . _ @ -, starting with a letter or digit")
    return clean


def _check_role(role: str) -> str:
    if role not in ROLES:
        raise FleetKeyError(f"role {role!r} is not one of: {', '.join(ROLES)}")
    return role


class TokenStoreKeys:
    """The dashboard's named tokens as fleet keys: ``store.find(name)`` returning an entry with
    ``name``, ``role`` and ``token`` (``curio.web.tokens.TokenStore``); duck-typed, so this
    module does not import the web layer."""

    def __init__(self, store: Any) -> None:
        self.store = store

    def key(self, name: str) -> KeyEntry | None:
        """The token called ``name`` as a key (None when there is none)."""
        try:
            entry = self.store.find(name)
        except Exception:
            return None
        role = str(getattr(entry, "role", ""))
        token = str(getattr(entry, "token", ""))
        if role not in ROLES or len(token) < 16:
            return None
        return KeyEntry(str(entry.name), role, token)


class ChainedKeys:
    """Looks a key up in each source in turn (the first that knows it wins)."""

    def __init__(self, sources: Sequence[KeyLookup]) -> None:
        self.sources = list(sources)

    def key(self, name: str) -> KeyEntry | None:
        """The first source's key called ``name``."""
        for source in self.sources:
            entry = source.key(name)
            if entry is not None:
                return entry
        return None
