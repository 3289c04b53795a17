"""The path manager: named paths of waypoints in ``map``, edited by the operator, persisted.

Replaces the original's ``follow_path.py`` data half (original-system.md §3.1, §3.5). Path 0 is
*Home* and cannot be deleted; paths 1 and 2 (and any more) come from ``cfg.bt.paths`` the first
time. Paths of any length are built by clicking points on the dashboard map (each with an
optional heading), renamed and deleted. Every change is written atomically to
``cfg.data_path(cfg.bt.paths_file)`` before the call returns, and again to ``<name>.bak`` (two
copies), so nothing is lost on a restart or a power loss. A file that cannot be read is moved
aside (``<name>.corrupt-N``) and replaced by its backup (:attr:`PathManager.restored` says so);
when the backup cannot be used either, that is reported in :attr:`PathManager.load_warning`
and the configured defaults are used.

Ids are never reused: a deleted path's id stays retired (``next_id`` is persisted), so a stale
command for a deleted path is rejected instead of driving a different path.

Units: metres and radians in ``map`` (REP-103/105). The config gives headings in degrees.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from curio.core.config import PathConfig
from curio.core.fileio import atomic_write_bytes, atomic_write_json

__all__ = [
    "HOME_PATH_ID",
    "MAX_NAME_CHARS",
    "MAX_PATHS",
    "MAX_WAYPOINTS",
    "NamedPath",
    "PathError",
    "PathManager",
    "Waypoint",
    "format_xy",
]

log = logging.getLogger("curio.bt.paths")

HOME_PATH_ID = 0
MAX_WAYPOINTS = 1000
MAX_PATHS = 500
MAX_NAME_CHARS = 60
MAX_COORD_M = 10_000.0
FILE_VERSION = 1


class PathError(ValueError):
    """A path edit or selection that cannot be done; ``str()`` is a sentence for the operator."""


def _num(value: float) -> str:
    """Format a coordinate the way the original printed it: ``0.2``, ``0``, ``-0.2``, ``1``."""
    rounded = round(value, 3) + 0.0  # + 0.0 turns -0.0 into 0.0
    return f"{rounded:g}"


def format_xy(x_m: float, y_m: float) -> str:
    """The operator-facing ``(x,y)`` token: numbers Python-style, comma, no space."""
    return f"({_num(x_m)},{_num(y_m)})"


@dataclass(frozen=True, slots=True)
class Waypoint:
    """A waypoint in ``map``: position in metres, optional heading in radians (None = any)."""

    x_m: float
    y_m: float
    yaw_rad: float | None = None

    def label(self) -> str:
        """``(x,y)`` as shown to the operator."""
        return format_xy(self.x_m, self.y_m)


@dataclass(slots=True)
class NamedPath:
    """A path of the path manager: ``id`` (0 = Home), a name and its waypoints in order."""

    id: int
    name: str
    waypoints: list[Waypoint] = field(default_factory=list)

    def copy(self) -> NamedPath:
        """An independent copy (callers may keep it while the manager changes)."""
        return NamedPath(self.id, self.name, list(self.waypoints))

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form (also used by the dashboard)."""
        return {
            "id": self.id,
            "name": self.name,
            "waypoints": [
                {"x_m": w.x_m, "y_m": w.y_m, "yaw_rad": w.yaw_rad} for w in self.waypoints
            ],
        }


def _check_coord(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PathError(f"{what} must be a number of metres, got {value!r}.")
    number = float(value)
    if not math.isfinite(number) or abs(number) > MAX_COORD_M:
        raise PathError(f"{what} must be a finite number of metres within ±{MAX_COORD_M:g}, "
                        f"got {value!r}.")
    return round(number, 4)


def _check_yaw(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PathError(f"the heading must be a number of radians or empty, got {value!r}.")
    number = float(value)
    if not math.isfinite(number):
        raise PathError(f"the heading must be a finite number of radians, got {value!r}.")
    return round(math.remainder(number, 2.0 * math.pi), 6)


def _check_name(value: Any) -> str:
    if not isinstance(value, str):
        raise PathError(f"a path name must be text, got {value!r}.")
    name = " ".join(value.split())
    if not name:
        raise PathError("a path name cannot be empty.")
    if len(name) > MAX_NAME_CHARS:
        raise PathError(f"a path name can have at most {MAX_NAME_CHARS} characters "
                        f"(this one has {len(name)}).")
    return name


def make_waypoint(x_m: Any, y_m: Any, yaw_rad: Any = None) -> Waypoint:
    """Validate and build a waypoint (raises :class:`PathError` with a sentence)."""
    return Waypoint(_check_coord(x_m, "x"), _check_coord(y_m, "y"), _check_yaw(yaw_rad))


def paths_from_config(configs: Sequence[PathConfig]) -> list[NamedPath]:
    """The configured default paths (index = id; headings converted from degrees)."""
    out: list[NamedPath] = []
    for index, pc in enumerate(configs):
        yaws: list[float | None] = (
            [math.radians(y) for y in pc.yaw_deg] if pc.yaw_deg is not None
            else [None] * len(pc.points)
        )
        name = pc.name or ("Home" if index == HOME_PATH_ID else f"Path {index}")
        wps = [make_waypoint(x, y, yaw) for (x, y), yaw in zip(pc.points, yaws, strict=True)]
        out.append(NamedPath(index, name, wps))
    if not out:
        out.append(NamedPath(HOME_PATH_ID, "Home", [Waypoint(0.0, 0.0, 0.0)]))
    return out


class PathManager:
    """Named paths (0 = Home) with validated edits, persisted atomically after every change.

    Args:
        defaults: the configured paths (``cfg.bt.paths``); used when no file exists yet or the
            file is unreadable.
        file: where the paths are kept (``cfg.data_path(cfg.bt.paths_file)``); None keeps them
            in memory only (tests, benchmarks).

    Every method raises :class:`PathError` (a ``ValueError``) whose message is a sentence for
    the operator. Listeners added with :meth:`add_listener` are called after each change.
    """

    def __init__(
        self,
        defaults: Sequence[PathConfig] | Sequence[NamedPath],
        file: Path | None = None,
    ) -> None:
        configs = [d for d in defaults if isinstance(d, PathConfig)]
        given = [d.copy() for d in defaults if isinstance(d, NamedPath)]
        self._defaults: list[NamedPath] = given or paths_from_config(configs)
        if all(p.id != HOME_PATH_ID for p in self._defaults):
            self._defaults.insert(0, NamedPath(HOME_PATH_ID, "Home", [Waypoint(0.0, 0.0, 0.0)]))
        self._file = file
        self._paths: dict[int, NamedPath] = {}
        self._next_id = 0
        self._listeners: list[Callable[[str, int], None]] = []
        self.load_warning: str | None = None
        self.restored: str | None = None
        self._load()

    # --- persistence ------------------------------------------------------------------------

    def _use_defaults(self) -> None:
        self._paths = {p.id: p.copy() for p in self._defaults}
        self._next_id = max(self._paths) + 1

    def _load(self) -> None:
        if self._file is None or not self._file.exists():
            self._use_defaults()
            if self._file is not None:
                self._save()
            return
        try:
            data = json.loads(self._file.read_text(encoding="utf-8"))
            paths, next_id = self._parse(data)
        except (OSError, ValueError, TypeError, KeyError) as exc:
            if self._restore_backup(exc):
                return
            aside = self._move_aside()
            self.load_warning = (
                f"The saved paths in {self._file} could not be read ({exc}); the file was kept "
                f"as {aside.name if aside else 'is'} and the configured paths are used."
            )
            log.error("%s", self.load_warning)
            self._use_defaults()
            self._save()
            return
        self._paths = paths
        self._next_id = next_id

    @staticmethod
    def _parse(data: Any) -> tuple[dict[int, NamedPath], int]:
        if not isinstance(data, dict) or data.get("version") != FILE_VERSION:
            raise ValueError(f"not a version-{FILE_VERSION} paths file")
        paths: dict[int, NamedPath] = {}
        for item in data["paths"]:
            pid = item["id"]
            if not isinstance(pid, int) or isinstance(pid, bool) or pid < 0 or pid in paths:
                raise ValueError(f"bad or repeated path id {pid!r}")
            wps = [make_waypoint(w["x_m"], w["y_m"], w.get("yaw_rad"))
                   for w in item["waypoints"]]
            paths[pid] = NamedPath(pid, _check_name(item["name"]), wps)
        if HOME_PATH_ID not in paths or not paths[HOME_PATH_ID].waypoints:
            raise ValueError("path 0 (Home) is missing or empty")
        next_id = data.get("next_id", max(paths) + 1)
        if not isinstance(next_id, int) or next_id <= max(paths):
            next_id = max(paths) + 1
        return paths, next_id

    @property
    def backup(self) -> Path | None:
        """The second copy of the last save (``<name>.bak``)."""
        return None if self._file is None else self._file.with_name(self._file.name + ".bak")

    def _restore_backup(self, problem: Exception) -> bool:
        """The file cannot be used: use its backup if that one can (the damaged file is kept
        as ``<name>.corrupt-N``); True when it could."""
        backup = self.backup
        if backup is None:
            return False
        try:
            paths, next_id = self._parse(json.loads(backup.read_text(encoding="utf-8")))
        except (OSError, ValueError, TypeError, KeyError):
            return False
        assert self._file is not None
        aside = self._move_aside()
        atomic_write_bytes(self._file, backup.read_bytes())
        self._paths, self._next_id = paths, next_id
        self.restored = (f"the paths file {self._file.name} could not be used ({problem}); its "
                         f"backup {backup.name} was put in its place"
                         + (f" and the damaged file kept as {aside.name}" if aside else ""))
        log.warning("%s", self.restored)
        return True

    def _move_aside(self) -> Path | None:
        assert self._file is not None
        for n in range(1, 1000):
            aside = self._file.with_name(f"{self._file.name}.corrupt-{n}")
            if not aside.exists():
                try:
                    self._file.rename(aside)
                except OSError:
                    return None
                return aside
        return None

    def _save(self) -> None:
        if self._file is None:
            return
        body = {"version": FILE_VERSION, "next_id": self._next_id,
                "paths": [self._paths[pid].to_json() for pid in sorted(self._paths)]}
        atomic_write_json(self._file, body)
        backup = self.backup
        assert backup is not None
        try:
            atomic_write_json(backup, body)  # a second copy: a damaged file is replaced by it
        except OSError as exc:  # the edit is saved; only its second copy is behind
            log.warning("could not update the paths backup %s: %s", backup, exc)

    def _snapshot(self) -> tuple[dict[int, NamedPath], int]:
        return {pid: p.copy() for pid, p in self._paths.items()}, self._next_id

    def _changed(self, what: str, path_id: int, before: tuple[dict[int, NamedPath], int]
                 ) -> None:
        """Save after an edit; when the file cannot be written (a full disk), undo the edit
        (``before``: :meth:`_snapshot` taken before it) and say so: an edit the operator was
        told failed must not reach the file with the next successful save."""
        try:
            self._save()
        except OSError as exc:
            self._paths, self._next_id = before
            log.error("could not save the paths to %s: %s", self._file, exc)
            raise PathError(f"Could not save the paths ({exc.strerror or exc}): nothing was "
                            "changed. Free space on the rover's disk, then try again.") from exc
        for listener in list(self._listeners):
            try:
                listener(what, path_id)
            except Exception:  # a broken listener must not lose the edit
                log.exception("path listener failed")

    def add_listener(self, listener: Callable[[str, int], None]) -> None:
        """Call ``listener(what, path_id)`` after each change (``what``: created, changed,
        renamed, deleted)."""
        self._listeners.append(listener)

    # --- queries ----------------------------------------------------------------------------

    @property
    def file(self) -> Path | None:
        """Where the paths are persisted (None = in memory)."""
        return self._file

    def list_paths(self) -> list[NamedPath]:
        """Every path, by id (copies)."""
        return [self._paths[pid].copy() for pid in sorted(self._paths)]

    def ids(self) -> list[int]:
        """The ids of every path, ascending."""
        return sorted(self._paths)

    def describe(self) -> str:
        """``0 Home, 1 Path 1, ...`` for operator messages."""
        return ", ".join(f"{p.id} ({p.name})" for p in self.list_paths())

    def get(self, path_id: int) -> NamedPath:
        """The path ``path_id`` (a copy).

        Raises:
            PathError: there is no such path (the message lists the paths there are).
        """
        if isinstance(path_id, bool) or not isinstance(path_id, int):
            raise PathError(f"a path number must be a whole number, got {path_id!r}.")
        path = self._paths.get(path_id)
        if path is None:
            raise PathError(f"There is no path {path_id}. The paths are: {self.describe()}.")
        return path.copy()

    # --- edits ------------------------------------------------------------------------------

    def create(self, name: str, waypoints: Sequence[Waypoint] = ()) -> NamedPath:
        """Create a path (it may be empty: add waypoints by clicking) and return it."""
        clean = _check_name(name)
        if len(self._paths) >= MAX_PATHS:
            raise PathError(f"There are already {MAX_PATHS} paths; delete one first.")
        wps = [make_waypoint(w.x_m, w.y_m, w.yaw_rad) for w in waypoints]
        if len(wps) > MAX_WAYPOINTS:
            raise PathError(f"A path can have at most {MAX_WAYPOINTS} waypoints.")
        before = self._snapshot()
        path = NamedPath(self._next_id, clean, wps)
        self._paths[path.id] = path
        self._next_id += 1
        self._changed("created", path.id, before)
        return path.copy()

    def _editable(self, path_id: int) -> NamedPath:
        self.get(path_id)  # raises the operator's message for unknown ids
        return self._paths[path_id]

    def add_waypoint(
        self, path_id: int, x_m: float, y_m: float, yaw_rad: float | None = None
    ) -> NamedPath:
        """Append a waypoint (metres/radians in ``map``) to path ``path_id``."""
        path = self._editable(path_id)
        if len(path.waypoints) >= MAX_WAYPOINTS:
            raise PathError(f"Path {path_id} already has {MAX_WAYPOINTS} waypoints, the most "
                            "a path can have.")
        before = self._snapshot()
        path.waypoints.append(make_waypoint(x_m, y_m, yaw_rad))
        self._changed("changed", path_id, before)
        return path.copy()

    def remove_waypoint(self, path_id: int, index: int) -> NamedPath:
        """Remove waypoint ``index`` (0-based; negative counts from the end)."""
        path = self._editable(path_id)
        n = len(path.waypoints)
        if isinstance(index, bool) or not isinstance(index, int) or not -n <= index < n:
            if n == 0:
                raise PathError(f"Path {path_id} ({path.name}) has no waypoints to remove.")
            raise PathError(f"Path {path_id} ({path.name}) has waypoints 0 to {n - 1}; "
                            f"there is no waypoint {index!r}.")
        if path_id == HOME_PATH_ID and n == 1:
            raise PathError("Home must keep its waypoint; add another before removing this one.")
        before = self._snapshot()
        del path.waypoints[index]
        self._changed("changed", path_id, before)
        return path.copy()

    def replace_waypoints(self, path_id: int, waypoints: Sequence[Waypoint]) -> NamedPath:
        """Give path ``path_id`` these waypoints, in this order (moves, inserts and reorders
        from the dashboard in one validated, atomic change)."""
        path = self._editable(path_id)
        wps = [make_waypoint(w.x_m, w.y_m, w.yaw_rad) for w in waypoints]
        if len(wps) > MAX_WAYPOINTS:
            raise PathError(f"A path can have at most {MAX_WAYPOINTS} waypoints.")
        if path_id == HOME_PATH_ID and not wps:
            raise PathError("Home must keep at least one waypoint.")
        before = self._snapshot()
        path.waypoints = wps
        self._changed("changed", path_id, before)
        return path.copy()

    def set_home(self, x_m: float, y_m: float, yaw_rad: float | None) -> NamedPath:
        """Move home: the last waypoint of path 0 (the waypoints before it are the route home).

        Home is the one named pose that is also the dock (``curio/docking/home.py``): the start
        pose after a restart and where Go Home (and docking) ends.
        """
        path = self._paths[HOME_PATH_ID]
        home = make_waypoint(x_m, y_m, yaw_rad)
        before = self._snapshot()
        path.waypoints[-1] = home
        self._changed("changed", HOME_PATH_ID, before)
        return path.copy()

    def rename(self, path_id: int, name: str) -> NamedPath:
        """Rename path ``path_id``."""
        path = self._editable(path_id)
        clean = _check_name(name)
        before = self._snapshot()
        path.name = clean
        self._changed("renamed", path_id, before)
        return path.copy()

    def delete(self, path_id: int) -> None:
        """Delete path ``path_id`` (not Home). Its id is never given to another path."""
        if path_id == HOME_PATH_ID:
            raise PathError("Home (path 0) cannot be deleted.")
        self._editable(path_id)
        before = self._snapshot()
        del self._paths[path_id]
        self._changed("deleted", path_id, before)
