"""A map's zones, kept by the fleet manager and pushed to the rovers that drive on that map.

The manager keeps the zones of its shared map in the same file a rover does
(``<data_dir>/<zones.directory>/<map name>.json``, :class:`~curio.zones.store.ZoneStore`; edit
it with a rover's dashboard and copy it over, or by hand, and check it with ``curio zones
list``). Each rover publishes, in its status, the map name and a digest of its zones
(:func:`zones_status`); the manager's :class:`ZoneDistributor` compares, every check, each
online rover's digest with its own and sends the whole set as a signed ``set_zones`` command
(``{"map", "zones"}``, permission ``zones``: an operator's or admin's key) to those that
differ — at most every ``RESEND_S`` per rover, so a rover that refuses (a keep-out zone over
where it stands or over its dock, another map) is asked again later, not flooded. The rover
takes the set through :meth:`curio.zones.service.ZoneService.replace`, which checks it like
an edit on its dashboard and applies it to the costmap, the controller and the safety stage.

A rover that has zones of its own on that map loses them to the manager's: the manager's file
is the fleet's one source of truth for a shared map — once it exists (without a file the
manager pushes nothing, so rovers keep the zones they have). A rover on another map is left alone
(and is flagged on the fleet page by its map fingerprint).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from curio.fleet.manager.roster import Roster
from curio.zones.store import ZoneStore

__all__ = ["RESEND_S", "ZoneDistributor", "zones_digest", "zones_status"]

RESEND_S = 10.0


def zones_digest(zones: list[dict[str, Any]]) -> str:
    """A short digest of a list of zones (their JSON form), equal for equal sets."""
    text = json.dumps(zones, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def zones_status(service: Any) -> Callable[[], dict[str, Any]]:
    """For the rover's status: ``{"zones": {"map", "revision", "digest", "count"}}`` of a
    :class:`~curio.zones.service.ZoneService` (``None`` when zones are off)."""
    def status() -> dict[str, Any]:
        if service is None:
            return {"zones": None}
        listed = service.list_zones()
        return {"zones": {"map": listed["map"], "revision": listed["revision"],
                          "digest": zones_digest(listed["zones"]),
                          "count": len(listed["zones"])}}
    return status


class ZoneDistributor:
    """The manager's side (see the module docstring).

    Args:
        path: the manager's zone file of the shared map.
        map_name: the shared map's name (the file's stem).
        max_speed_mps: the rovers' top speed (speed limits are checked against it).
        roster: the rovers as the manager hears them.
        send: signs and sends a command to a rover.
        note: records a ``zones.*`` event.
    """

    def __init__(self, path: Path, map_name: str, max_speed_mps: float, roster: Roster,
                 send: Callable[[str, dict[str, Any]], None],
                 note: Callable[[str, dict[str, Any]], None]) -> None:
        self.path = path
        self.map_name = map_name
        self.max_speed_mps = max_speed_mps
        self.roster = roster
        self.send = send
        self.note = note
        self.zones: list[dict[str, Any]] = []
        self.digest = zones_digest([])
        self._mtime: int | None = None  # of the file read (None: there is none)
        self._loaded = False
        self._sent: dict[str, float] = {}
        self.pushes = 0
        self.reload()

    @property
    def has_file(self) -> bool:
        """Whether the manager has a zone file for the map (else it pushes nothing)."""
        return self._mtime is not None

    def reload(self) -> bool:
        """Read the zone file again when it changed; True when it did."""
        try:
            mtime: int | None = self.path.stat().st_mtime_ns
        except OSError:
            mtime = None
        if self._loaded and mtime == self._mtime:
            return False
        self._loaded = True
        self._mtime = mtime
        store = ZoneStore(self.path, self.map_name, self.max_speed_mps)
        self.zones = [z.to_json() for z in store.list_zones()]
        self.digest = zones_digest(self.zones)
        self._sent.clear()
        return True

    def check(self, now_wall_s: float, offline_after_s: float) -> list[str]:
        """Send the zones to every online rover on the map whose zones differ; return them.
        Nothing while the manager has no zone file (it would wipe the rovers' own zones)."""
        out: list[str] = []
        if self._mtime is None:
            return out
        for name, r in sorted(self.roster.rovers.items()):
            theirs = r.status.get("zones")
            if not isinstance(theirs, dict) or theirs.get("map") != self.map_name:
                continue
            if theirs.get("digest") == self.digest or not r.online(now_wall_s,
                                                                     offline_after_s):
                continue
            if now_wall_s - self._sent.get(name, -math.inf) < RESEND_S:
                continue
            self._sent[name] = now_wall_s
            self.pushes += 1
            self.send(name, {"action": "set_zones", "map": self.map_name, "zones": self.zones,
                             "request_id": f"zones-{self.digest[:8]}-{self.pushes}"})
            self.note("zones.sent", {"rover": name, "map": self.map_name,
                                     "zones": len(self.zones), "digest": self.digest})
            out.append(name)
        return out
