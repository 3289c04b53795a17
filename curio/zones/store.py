"""The zones of one map, persisted: ``<data_dir>/<zones.directory>/<map name>.json``.

:class:`ZoneStore` keeps the zones of the navigation map in a versioned JSON file, written
before every call returns (temporary file, fsync, rename: ``curio.core.fileio``), the previous
good file kept as ``.bak``. Zone ids are never reused (``next_id`` is persisted). A file that
cannot be read is refused with the file and the problem (:class:`ZoneFileError`, a
``SetupError``: ``curio run`` stops with one line), so zones are never silently lost.

File (version 1)::

    {"version": 1, "map": "curio_building", "revision": 3, "next_id": 3,
     "zones": [{"id": 1, "name": "Stairs", "kind": "keepout", "polygon": [[x, y], ...],
                "speed_limit_mps": null}, ...]}

Each change bumps ``revision``; an edit may carry ``expect_revision`` (another operator changed
the zones meanwhile: refused rather than overwritten). Listeners are called after every change.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_json

from .model import Zone, ZoneError, make_zone

__all__ = ["FILE_VERSION", "ZoneFileError", "ZoneStore"]

FILE_VERSION = 1
MAX_ZONES = 500


class ZoneFileError(SetupError):
    """A zone file that cannot be used (names the file and the problem)."""


class ZoneStore:
    """CRUD on the zones of one map (see the module docstring).

    Args:
        path: the zone file (created on the first change).
        map_name: the map's name (stored in the file, checked on load).
        max_speed_mps: the rover's top speed (speed limits must be below it).
    """

    def __init__(self, path: Path, map_name: str, max_speed_mps: float) -> None:
        self.path = path
        self.map_name = map_name
        self.max_speed_mps = max_speed_mps
        self.revision = 0
        self._next_id = 1
        self._zones: dict[int, Zone] = {}
        self._listeners: list[Callable[[str, int], None]] = []
        self._load()

    # --- reading ------------------------------------------------------------------------------
    def list_zones(self) -> list[Zone]:
        """Every zone, by id."""
        return [self._zones[k] for k in sorted(self._zones)]

    def get(self, zone_id: int) -> Zone:
        """One zone (ZoneError naming the ids there are)."""
        try:
            return self._zones[zone_id]
        except KeyError:
            raise ZoneError(f"there is no zone {zone_id}; the zones are "
                            f"{sorted(self._zones) or 'none yet'}") from None

    def to_json(self) -> dict[str, Any]:
        """The file's content."""
        return {"version": FILE_VERSION, "map": self.map_name, "revision": self.revision,
                "next_id": self._next_id, "zones": [z.to_json() for z in self.list_zones()]}

    def add_listener(self, fn: Callable[[str, int], None]) -> None:
        """Call ``fn(change, zone_id)`` after each change (``added``, ``updated``,
        ``deleted``)."""
        self._listeners.append(fn)

    # --- editing ------------------------------------------------------------------------------
    def add(self, name: Any, kind: Any, polygon: Any, speed_limit_mps: Any = None, *,
            expect_revision: int | None = None) -> Zone:
        """Create a zone; return it.

        Raises:
            ZoneError: a bad field, too many zones, or a stale ``expect_revision``.
        """
        self._check_revision(expect_revision)
        if len(self._zones) >= MAX_ZONES:
            raise ZoneError(f"this map has {MAX_ZONES} zones, the most allowed; delete one "
                            "first")
        zone = make_zone(self._next_id, name, kind, polygon, speed_limit_mps,
                         self.max_speed_mps)
        self._zones[zone.id] = zone
        self._next_id += 1
        self._commit("added", zone.id)
        return zone

    def update(self, zone_id: int, *, expect_revision: int | None = None,
               **fields: Any) -> Zone:
        """Change ``name``, ``kind``, ``polygon`` and/or ``speed_limit_mps`` of a zone."""
        self._check_revision(expect_revision)
        unknown = set(fields) - {"name", "kind", "polygon", "speed_limit_mps"}
        if unknown:
            raise ZoneError(f"cannot change {sorted(unknown)}; a zone has name, kind, polygon "
                            "and speed_limit_mps")
        old = self.get(zone_id).to_json()
        merged = {**old, **fields}
        if fields.get("kind") == "keepout" and "speed_limit_mps" not in fields:
            merged["speed_limit_mps"] = None
        zone = make_zone(zone_id, merged["name"], merged["kind"], merged["polygon"],
                         merged["speed_limit_mps"], self.max_speed_mps)
        self._zones[zone_id] = zone
        self._commit("updated", zone_id)
        return zone

    def delete(self, zone_id: int, *, expect_revision: int | None = None) -> None:
        """Delete a zone."""
        self._check_revision(expect_revision)
        self.get(zone_id)
        del self._zones[zone_id]
        self._commit("deleted", zone_id)

    def replace_all(self, zones: list[Zone]) -> None:
        """Replace every zone with ``zones`` (their ids kept; a fleet manager's copy of the
        map's zones, ``curio/fleet/zones_sync.py``); one change, ``replaced``."""
        if len(zones) > MAX_ZONES:
            raise ZoneError(f"{len(zones)} zones is more than the {MAX_ZONES} allowed")
        if len({z.id for z in zones}) != len(zones):
            raise ZoneError("two zones have the same id")
        self._zones = {z.id: z for z in zones}
        self._next_id = max([self._next_id, *(z.id + 1 for z in zones)])
        self._commit("replaced", 0)

    # --- persistence --------------------------------------------------------------------------
    def _check_revision(self, expect: int | None) -> None:
        if expect is not None and expect != self.revision:
            raise ZoneError(f"the zones were changed meanwhile (revision {self.revision}, you "
                            f"edited revision {expect}); reload them and edit again")

    def _commit(self, change: str, zone_id: int) -> None:
        self.revision += 1
        if self.path.is_file():
            try:
                json.loads(self.path.read_text(encoding="utf-8"))
                shutil.copyfile(self.path, self.path.with_suffix(".json.bak"))
            except (OSError, ValueError):
                pass  # keep the last good backup
        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.path, self.to_json())
        for fn in list(self._listeners):
            fn(change, zone_id)

    def _load(self) -> None:
        if not self.path.exists():
            return
        where = f"{self.path}"
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ZoneFileError(f"{where}: cannot read the zone file ({exc}); fix it or restore "
                                f"{self.path.name}.bak") from None
        if not isinstance(data, dict) or data.get("version") != FILE_VERSION:
            raise ZoneFileError(f"{where}: not a version {FILE_VERSION} zone file; fix it or "
                                f"restore {self.path.name}.bak")
        try:
            zones = [Zone.from_json(z, self.max_speed_mps) for z in data.get("zones", [])]
            revision = int(data.get("revision", 0))
            next_id = int(data.get("next_id", 1))
        except (ZoneError, TypeError, ValueError) as exc:
            raise ZoneFileError(f"{where}: {exc}; fix it or restore {self.path.name}.bak") \
                from None
        self._zones = {z.id: z for z in zones}
        self.revision = revision
        self._next_id = max([next_id, *(z.id + 1 for z in zones)])
