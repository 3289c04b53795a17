"""The shared map, kept by the fleet manager and pushed to the rovers that drive on it.

The manager's map is the map file of its configuration (``map.yaml``; ``curio fleet run
--config``): when that file changes (a new revision copied over, an edit saved), the manager
reads it again (:meth:`MapDistributor.reload`). Each rover publishes, in its status, the name
of the map it drives on (``map_name``, :func:`map_name_status`) and the fingerprint of its cells
(``map``); every check, the manager sends the map as a signed ``set_map`` command
(``{"map", "grid", "sha"}``: :func:`encode_pushed_map`, permission ``maps``: an operator's or
admin's key) to every online rover **on that map** whose fingerprint differs — at most every
``fleet.manager.map_resend_s`` per rover, because a rover that is busy refuses and is asked
again later.

The rover (:class:`~curio.fleet.commands.CommandExecutor`, ``set_map``) takes it only when it
is safe: the map is the one it drives on (a rover is never moved to another building from the
network: that is done on its own dashboard, where somebody sets its pose), it is parked (no
goal, no tour, no map change under way), the map has free space at its home; then it keeps the
map as a new revision in its map library (the old one stays restorable on the Maps page) and
restarts on it the way a saved edit does (``curio run``'s host,
:class:`~curio.commands.host.MapHost`: the rover stops first, keeps its pose). A rover on
another map is left alone, flagged on the fleet page.
"""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from curio.core.messages import GridMessage
from curio.estimation.maps import OccupancyGrid, load_map
from curio.fleet import codec
from curio.fleet.manager.roster import Roster

__all__ = ["MapDistributor", "decode_pushed_map", "encode_pushed_map", "map_name_status",
           "map_payload"]


def map_payload(grid: OccupancyGrid) -> bytes:
    """``grid`` as :func:`~curio.fleet.codec.encode_map` bytes (the manager's ``q/map``)."""
    return codec.encode_map(GridMessage(0.0, grid.data, grid.resolution_m, grid.origin))


def encode_pushed_map(grid: OccupancyGrid) -> str:
    """``grid`` as text for a command: base64 of :func:`map_payload`."""
    return base64.b64encode(map_payload(grid)).decode("ascii")


def decode_pushed_map(text: Any, sha: Any, name: str) -> OccupancyGrid:
    """The grid of :func:`encode_pushed_map`'s text, checked against its fingerprint ``sha``.

    Raises:
        ValueError: not such a text, or its cells are not the fingerprint's.
    """
    if not isinstance(text, str) or not isinstance(sha, str):
        raise ValueError("set_map needs grid (the encoded map, text) and sha (its fingerprint)")
    try:
        message = codec.decode_map(base64.b64decode(text, validate=True))
    except (binascii.Error, codec.DecodeError, ValueError) as exc:
        raise ValueError(f"set_map: the map cannot be read ({exc})") from None
    if codec.grid_digest(message.data) != sha:
        raise ValueError("set_map: the map's cells do not match its fingerprint (damaged on "
                         "the way?)")
    if not (math.isfinite(message.resolution_m) and message.resolution_m > 0.0):
        raise ValueError(f"set_map: resolution {message.resolution_m} m is not a positive "
                         "number")
    return OccupancyGrid(message.data, message.resolution_m, message.origin, name=name)


def map_name_status(name: str) -> Callable[[], dict[str, Any]]:
    """For the rover's status: ``{"map_name": name}`` (the fingerprint is ``map``)."""
    return lambda: {"map_name": name}


class MapDistributor:
    """The manager's side (see the module docstring).

    Args:
        path: the manager's map YAML.
        map_name: the shared map's name (rovers report the same name: their map file's stem).
        roster: the rovers as the manager hears them.
        send: signs and sends a command to a rover.
        note: records a ``maps.*`` event.
        resend_s: at most one push per rover this often (it refuses while busy).
    """

    def __init__(self, path: Path, map_name: str, roster: Roster,
                 send: Callable[[str, dict[str, Any]], None],
                 note: Callable[[str, dict[str, Any]], None], resend_s: float) -> None:
        self.path = path
        self.map_name = map_name
        self.roster = roster
        self.send = send
        self.note = note
        self.resend_s = resend_s
        self._use(load_map(path))
        self._mtime = _mtime(path)
        self._sent: dict[str, float] = {}
        self.pushes = 0
        self.refused: dict[str, str] = {}  # why each rover last refused the map (the page)

    def reload(self) -> bool:
        """Read the map file again when it changed; True when its cells did. A file that
        cannot be read keeps the map in use (noted once)."""
        mtime = _mtime(self.path)
        if mtime == self._mtime:
            return False
        self._mtime = mtime
        try:
            grid = load_map(self.path)
        except (OSError, ValueError) as exc:
            self.note("maps.unreadable", {"map": self.map_name, "reason": str(exc)})
            return False
        if codec.grid_digest(grid.data) == self.sha:
            return False
        self._use(grid)
        self._sent.clear()
        self.note("maps.changed", {"map": self.map_name, "sha": self.sha})
        return True

    def _use(self, grid: OccupancyGrid) -> None:
        """Make ``grid`` the shared map: its fingerprint, its bytes (``q/map``), its text."""
        self.grid = grid
        self.sha = codec.grid_digest(grid.data)
        self.payload = map_payload(grid)
        self._text = base64.b64encode(self.payload).decode("ascii")

    def check(self, now_wall_s: float, offline_after_s: float) -> list[str]:
        """Send the map to every online rover on it whose cells differ; return them."""
        out: list[str] = []
        for name, r in sorted(self.roster.rovers.items()):
            theirs = r.status.get("map")
            if r.status.get("map_name") != self.map_name or not theirs or theirs == self.sha:
                self.refused.pop(name, None)
                continue
            if not r.online(now_wall_s, offline_after_s):
                continue
            if now_wall_s - self._sent.get(name, -math.inf) < self.resend_s:
                continue
            self._sent[name] = now_wall_s
            self.pushes += 1
            self.send(name, {"action": "set_map", "map": self.map_name, "grid": self._text,
                             "sha": self.sha,
                             "request_id": f"map-{self.sha[:8]}-{self.pushes}"})
            self.note("maps.sent", {"rover": name, "map": self.map_name, "sha": self.sha,
                                    "theirs": theirs})
            out.append(name)
        return out

    def on_reply(self, rover: str, reply: dict[str, Any]) -> None:
        """A rover's answer to a push: noted as ``maps.taken`` or ``maps.refused`` (why)."""
        if not str(reply.get("request_id", "")).startswith("map-"):
            return
        if reply.get("ok"):
            self.refused.pop(rover, None)
            self.note("maps.taken", {"rover": rover, "map": self.map_name,
                                     "detail": str(reply.get("reason", ""))})
        else:
            self.refused[rover] = str(reply.get("reason", ""))
            self.note("maps.refused", {"rover": rover, "map": self.map_name,
                                       "reason": self.refused[rover]})


def _mtime(path: Path) -> int | None:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return None
