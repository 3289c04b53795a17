"""Named dashboard tokens and the roles they grant, kept in ``<data_dir>/<web.tokens_file>``.

Roles (what each may do is :data:`PERMISSIONS`):

* **viewer** — no token: watch everything, change nothing.
* **kiosk** — start and stop tours only (a lobby screen; the ``/kiosk`` page uses it).
* **operator** — drive, send goals and paths, edit paths, tours and schedules, manage maps
  (the library, switching, mapping runs, cell edits), set the pose,
  e-stop, download the event log and recordings; release an e-stop it set itself (or one the
  rover set).
* **admin** — everything an operator may, and release anybody's e-stop.

The file is JSON ``{"version": 1, "tokens": [{"name", "role", "token", "created"}]}``, mode
0600, written atomically. ``curio token`` (:mod:`curio.commands.token`) creates, lists, revokes
and rotates tokens; the running server notices the change within a second (the file's mtime)
and closes the sockets of a revoked token. On the first start the store is created with one
admin token named ``admin``; an install from before named tokens (a single token in
``<data_dir>/web_token``) is migrated: that token becomes the admin token ``admin`` and the old
file is removed.

Tokens are compared in constant time, against every stored token (a presented token's hash
with each stored hash), and are never logged.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import secrets
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_text, modified_ns

__all__ = [
    "NAME_RULE",
    "PERMISSIONS",
    "ROLES",
    "Identity",
    "Role",
    "TokenEntry",
    "TokenError",
    "TokenStore",
    "new_secret",
]

log = logging.getLogger("curio.web.tokens")

Role = Literal["viewer", "kiosk", "operator", "admin"]
# Roles a token can have (viewer is what no token gives).
ROLES: tuple[str, ...] = ("kiosk", "operator", "admin")
FILE_VERSION = 1
_SECRET_BYTES = 24
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9 ._@-]{0,31}$")
NAME_RULE = "1–32 letters, digits, spaces or . _ @ -, starting with a letter or digit"

# What each role may do. The permission names are used by the REST API, the WebSocket and
# :func:`action_permission`.
PERMISSIONS: dict[str, frozenset[str]] = {
    "viewer": frozenset(),
    "kiosk": frozenset({"tour"}),
    "operator": frozenset({"tour", "estop", "command", "drive", "paths", "initial_pose",
                           "tours", "zones", "data", "maps"}),
    "admin": frozenset({"tour", "estop", "command", "drive", "paths", "initial_pose",
                        "tours", "zones", "data", "maps", "release_any_estop"}),
}
PERMISSION_WORDS = {
    "tour": "start and stop tours",
    "estop": "use the e-stop",
    "command": "send commands",
    "drive": "drive by hand",
    "paths": "edit paths",
    "initial_pose": "set the rover's position",
    "tours": "edit tours and schedules",
    "zones": "edit keep-out and speed zones",
    "data": "download the event log and recordings",
    "maps": "manage, switch, make and edit maps",
    "release_any_estop": "release another operator's e-stop",
}


class TokenError(SetupError, ValueError):
    """A token command that cannot be done (unknown name, bad role, unreadable file)."""


@dataclass(frozen=True, slots=True)
class Identity:
    """Who a request or socket is: the token's name and role (``viewer`` without a token)."""

    name: str
    role: Role

    @property
    def permissions(self) -> frozenset[str]:
        """What this identity may do (see :data:`PERMISSIONS`)."""
        return PERMISSIONS[self.role]

    def may(self, permission: str) -> bool:
        """Whether this identity has ``permission``."""
        return permission in PERMISSIONS[self.role]

    @property
    def source(self) -> str:
        """The command source that names this operator (``web:<name>``, ``kiosk:<name>``)."""
        return f"{'kiosk' if self.role == 'kiosk' else 'web'}:{self.name}"


VIEWER = Identity("viewer", "viewer")


@dataclass(frozen=True, slots=True)
class TokenEntry:
    """One stored token: its name (shown to every page as who did what), role and secret."""

    name: str
    role: Role
    token: str
    created: str

    def identity(self) -> Identity:
        """The identity this token grants."""
        return Identity(self.name, self.role)

    def public(self) -> dict[str, str]:
        """Name, role, creation date and the secret's last four characters (for listings)."""
        return {"name": self.name, "role": self.role, "created": self.created,
                "ends_with": self.token[-4:]}


def new_secret() -> str:
    """A new random token: 32 URL-safe characters (192 bits)."""
    return secrets.token_urlsafe(_SECRET_BYTES)


def _digest(text: str) -> bytes:
    return hashlib.sha256(text.encode("utf-8", "surrogateescape")).digest()


def _check_name(name: str) -> str:
    clean = " ".join(name.split())
    if not _NAME.match(clean):
        raise TokenError(f"token name {name!r} is not allowed: use {NAME_RULE}")
    return clean


def _check_role(role: str) -> Role:
    if role not in ROLES:
        raise TokenError(f"role {role!r} is not one of: {', '.join(ROLES)}")
    return role  # type: ignore[return-value]


class TokenStore:
    """The named tokens in one file; every change is written at once (0600, atomically).

    Args:
        path: the tokens file (``cfg.data_path(cfg.web.tokens_file)``).
        legacy_path: the single-token file of older installs (``web.token_file``), migrated
            to the admin token ``admin`` the first time.
        clock_wall: returns UNIX time for creation dates (the injected clock's ``wall_time``).
    """

    def __init__(self, path: Path, legacy_path: Path | None = None,
                 clock_wall: Any = None) -> None:
        self.path = path
        self.legacy_path = legacy_path
        self._wall = clock_wall
        self._entries: list[TokenEntry] = []
        self._digests: list[tuple[bytes, TokenEntry]] = []
        self._mtime_ns: int | None = None
        self.load()

    # --- file -----------------------------------------------------------------------------------

    def _now_text(self) -> str:
        wall = self._wall() if self._wall is not None else datetime.now(UTC).timestamp()
        return datetime.fromtimestamp(wall, UTC).strftime("%Y-%m-%d %H:%M UTC")

    def load(self) -> None:
        """(Re)read the file; a missing file stays empty until :meth:`ensure_admin`.

        Raises:
            TokenError: the file exists but is not a tokens file (it names the file).
        """
        if not self.path.exists():
            self._set([])
            self._mtime_ns = None
            return
        try:
            stat = self.path.stat()
            data = json.loads(self.path.read_text(encoding="utf-8"))
            entries = self._parse(data)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise TokenError(f"the dashboard tokens file {self.path} cannot be read ({exc}); "
                             "fix it or move it away (a new admin token is then made)") from None
        if stat.st_mode & 0o077:
            os.chmod(self.path, 0o600)
        self._mtime_ns = stat.st_mtime_ns
        self._set(entries)

    @staticmethod
    def _parse(data: Any) -> list[TokenEntry]:
        if not isinstance(data, dict) or data.get("version") != FILE_VERSION:
            raise ValueError(f"not a version-{FILE_VERSION} tokens file")
        entries = []
        for item in data["tokens"]:
            token = str(item["token"])
            if len(token) < 16 or not token.isascii():
                raise ValueError(f"token {item.get('name')!r} is shorter than 16 characters")
            entries.append(TokenEntry(_check_name(str(item["name"])),
                                      _check_role(str(item["role"])), token,
                                      str(item.get("created", ""))))
        return entries

    def _set(self, entries: list[TokenEntry]) -> None:
        self._entries = entries
        self._digests = [(_digest(e.token), e) for e in entries]

    def _save(self) -> None:
        body = {"version": FILE_VERSION,
                "tokens": [{"name": e.name, "role": e.role, "token": e.token,
                            "created": e.created} for e in self._entries]}
        atomic_write_text(self.path, json.dumps(body, indent=2) + "\n", private=True)
        self._mtime_ns = self.path.stat().st_mtime_ns

    def reload_if_changed(self) -> bool:
        """Re-read the file if another process (``curio token``) changed it; True if it did.

        A file that became unreadable keeps the tokens in memory (and logs why).
        """
        mtime = modified_ns(self.path)
        if mtime == self._mtime_ns:
            return False
        try:
            self.load()
        except TokenError as exc:
            log.error("%s; keeping the tokens read before", exc)
            self._mtime_ns = mtime
            return False
        return True

    def ensure_admin(self) -> TokenEntry | None:
        """First start: migrate the legacy single token, or create the admin token ``admin``.

        Returns the admin token made now, or None when the file already existed.
        """
        if self.path.exists():
            return None
        legacy = self.legacy_path
        secret = None
        if legacy is not None and legacy.is_file():
            text = legacy.read_text(encoding="utf-8").strip()
            if len(text) >= 16 and text.isascii():
                secret = text
        entry = TokenEntry("admin", "admin", secret or new_secret(), self._now_text())
        self._entries = [entry]
        self._set(self._entries)
        self._save()
        if secret is not None and legacy is not None:
            legacy.unlink()
            log.info("the dashboard token of %s is now the admin token 'admin' in %s",
                     legacy.name, self.path.name)
        return entry

    # --- queries --------------------------------------------------------------------------------

    def entries(self) -> list[TokenEntry]:
        """Every token, in creation order."""
        return list(self._entries)

    def find(self, name: str) -> TokenEntry:
        """The token called ``name`` (case-insensitive).

        Raises:
            TokenError: there is none (the message lists the names there are).
        """
        for entry in self._entries:
            if entry.name.lower() == name.strip().lower():
                return entry
        names = ", ".join(e.name for e in self._entries) or "none"
        raise TokenError(f"there is no token named {name!r}; tokens: {names}")

    def identify(self, presented: str) -> TokenEntry | None:
        """The entry whose token is ``presented``, compared in constant time with every one."""
        digest = _digest(presented)
        found = None
        for stored, entry in self._digests:
            if secrets.compare_digest(stored, digest):
                found = entry
        return found

    def permits(self, presented: str, permission: str) -> bool:
        """Whether the token ``presented`` is one of ours and its role has ``permission``
        (other doors to the rover, e.g. live Foxglove's teleop, ask this)."""
        if not presented:
            return False
        self.reload_if_changed()
        entry = self.identify(presented)
        return entry is not None and entry.identity().may(permission)

    def first_admin(self) -> TokenEntry | None:
        """The admin token for the start-up URL: ``admin`` if there is one, else the first."""
        admins = [e for e in self._entries if e.role == "admin"]
        named = [e for e in admins if e.name == "admin"]
        chosen = named or admins
        return chosen[0] if chosen else None

    # --- changes --------------------------------------------------------------------------------

    def create(self, name: str, role: str) -> TokenEntry:
        """A new token called ``name`` with ``role``.

        Raises:
            TokenError: the name is taken or not allowed, or the role is unknown.
        """
        clean = _check_name(name)
        checked = _check_role(role)
        if any(e.name.lower() == clean.lower() for e in self._entries):
            raise TokenError(f"a token named {clean!r} exists already; rotate or revoke it")
        entry = TokenEntry(clean, checked, new_secret(), self._now_text())
        self._set([*self._entries, entry])
        self._save()
        return entry

    def revoke(self, name: str) -> TokenEntry:
        """Delete the token called ``name``; return what was deleted."""
        entry = self.find(name)
        self._set([e for e in self._entries if e is not entry])
        self._save()
        return entry

    def rotate(self, name: str) -> TokenEntry:
        """Give the token called ``name`` a new secret (same name and role)."""
        old = self.find(name)
        entry = TokenEntry(old.name, old.role, new_secret(), self._now_text())
        self._set([entry if e is old else e for e in self._entries])
        self._save()
        return entry

