"""The map library: every map the rover knows, on disk under ``<data_dir>/<maps.directory>/``.

One directory per map, named after it::

    maps/active.json            {"version": 1, "active": "<name>"}
    maps/<name>/map.json        {"version": 1, "name", "floor", "revision", "created_wall_s",
                                 "source"}
    maps/<name>/<name>.yaml     the current revision (map_server YAML + PGM beside it)
    maps/<name>/revisions/r<N>.yaml|pgm   every earlier revision, kept
    maps/<name>/world/…         the simulated building (YAML, PGM, .world.toml), if any
    maps/<name>/paths.json, tours.json, schedules.json   what belongs to the map (the App's;
                                 the first, seeded map keeps the ones in data_dir)

The zones of a map stay where issue 11 put them (``<data_dir>/<zones.directory>/<name>.json``);
renaming a map moves them. Every refusal is a :class:`MapLibraryError` with one sentence
naming the value, what is wrong and what is allowed. Writes go through
:mod:`curio.core.fileio` (write-then-rename) or a directory rename.
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from curio.core.fileio import atomic_write_bytes, atomic_write_json
from curio.estimation.maps import MapError, OccupancyGrid, load_map, save_map

__all__ = [
    "FLOOR_RULE",
    "NAME_RULE",
    "MapEntry",
    "MapLibrary",
    "MapLibraryError",
]

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,39}$")
NAME_RULE = "1–40 letters, digits, '-' or '_', starting with a letter or digit"
FLOOR_RULE = "up to 30 characters"
FILE_VERSION = 1
MAX_CELLS = 4096 * 4096


class MapLibraryError(ValueError):
    """A library request that cannot be done, with the sentence that says why."""


@dataclass(frozen=True)
class MapEntry:
    """One map of the library, as the list shows it.

    Attributes:
        name: the map's name (its directory).
        floor: the floor label ("" when not set).
        revision: the current revision (1 for a new map; +1 per saved edit).
        width_cells, height_cells: the grid's size in cells.
        resolution_m: the cell size, metres.
        width_m, height_m: the grid's extent, metres.
        origin: cell (0, 0)'s lower-left corner in ``map``: (x m, y m, yaw rad).
        has_world: a simulated building goes with it (``world/``).
        source: how it came (``shipped``, ``mapping``, ``upload``).
        created_wall_s: when it was added, UNIX seconds.
    """

    name: str
    floor: str
    revision: int
    width_cells: int
    height_cells: int
    resolution_m: float
    width_m: float
    height_m: float
    origin: tuple[float, float, float]
    has_world: bool
    source: str
    created_wall_s: float


def check_name(name: Any) -> str:
    """``name`` if it is a valid map name, else :class:`MapLibraryError`."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise MapLibraryError(f"map name {str(name)[:50]!r} is not allowed: use {NAME_RULE}")
    return name


def check_floor(floor: Any) -> str:
    """``floor`` stripped if it is a valid floor label, else :class:`MapLibraryError`."""
    if not isinstance(floor, str) or len(floor.strip()) > 30 or any(
            ord(c) < 32 for c in floor):
        raise MapLibraryError(f"floor {str(floor)[:50]!r} is not allowed: use {FLOOR_RULE} "
                              "of text")
    return floor.strip()


class MapLibrary:
    """The maps under ``root`` (see the module docstring); ``zones_dir`` holds their zones.

    Args:
        root: ``<data_dir>/<maps.directory>``.
        zones_dir: ``<data_dir>/<zones.directory>``.
        wall_time: UNIX seconds now (the injected clock's ``wall_time``).
    """

    def __init__(self, root: Path, zones_dir: Path, wall_time: Any) -> None:
        self.root = Path(root)
        self.zones_dir = Path(zones_dir)
        self._wall_time = wall_time
        self.root.mkdir(parents=True, exist_ok=True)

    # --- reading -----------------------------------------------------------------------------

    def names(self) -> list[str]:
        """Every map's name, sorted."""
        return sorted(p.name for p in self.root.iterdir()
                      if p.is_dir() and (p / "map.json").is_file() and _NAME.match(p.name))

    def exists(self, name: str) -> bool:
        """Whether the library has a map called ``name``."""
        return name in self.names()

    def map_yaml(self, name: str) -> Path:
        """The current revision's YAML of ``name`` (refused when there is no such map)."""
        self._need(name)
        return self.root / name / f"{name}.yaml"

    def world_yaml(self, name: str) -> Path | None:
        """The simulated building that goes with ``name`` (None: the map itself)."""
        worlds = sorted((self.root / name / "world").glob("*.yaml"))
        return worlds[0] if worlds else None

    def meta(self, name: str) -> dict[str, Any]:
        """``map.json`` of ``name``."""
        self._need(name)
        try:
            meta = json.loads((self.root / name / "map.json").read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise MapLibraryError(f"map {name!r}: its map.json cannot be read ({exc})") from None
        if not isinstance(meta, dict):
            raise MapLibraryError(f"map {name!r}: its map.json is not a JSON object")
        return meta

    def grid(self, name: str) -> OccupancyGrid:
        """The current revision of ``name``."""
        return load_map(self.map_yaml(name))

    def entry(self, name: str) -> MapEntry:
        """What the list shows of ``name``."""
        meta = self.meta(name)
        grid = self.grid(name)
        o = grid.origin
        return MapEntry(name, str(meta.get("floor", "")), int(meta.get("revision", 1)),
                        grid.width, grid.height, grid.resolution_m, grid.size_m[0],
                        grid.size_m[1], (o.x, o.y, o.yaw), self.world_yaml(name) is not None,
                        str(meta.get("source", "")), float(meta.get("created_wall_s", 0.0)))

    def revisions(self, name: str) -> list[int]:
        """The kept earlier revisions of ``name``, oldest first."""
        self._need(name)
        out = []
        for p in (self.root / name / "revisions").glob("r*.yaml"):
            if p.stem[1:].isdigit():
                out.append(int(p.stem[1:]))
        return sorted(out)

    # --- the active map ----------------------------------------------------------------------

    @property
    def active(self) -> str | None:
        """The active map's name (``active.json``), or None before the first start."""
        try:
            data = json.loads((self.root / "active.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        name = data.get("active") if isinstance(data, dict) else None
        return name if isinstance(name, str) and self.exists(name) else None

    def set_active(self, name: str) -> None:
        """Make ``name`` the active map (it survives a restart)."""
        self._need(name)
        atomic_write_json(self.root / "active.json", {"version": FILE_VERSION, "active": name})

    # --- adding ------------------------------------------------------------------------------

    def seed(self, map_yaml: Path, floor: str = "Ground floor") -> str:
        """The first start: add the configured map (with its simulated building) as the active
        map. Its paths, tours and schedules stay where they were (``data_dir/paths.json``, …:
        nothing is moved, so an existing install keeps them and an older version still finds
        them; ``keeps_data_dir`` in its ``map.json``). Later starts: nothing (return the active
        map)."""
        active = self.active
        if active is not None:
            return active
        name = re.sub(r"[^A-Za-z0-9_-]", "_", map_yaml.stem)[:40] or "map"
        if not self.exists(name):
            grid = load_map(map_yaml)
            self._write_new(name, grid, floor, "shipped", world_from=map_yaml,
                            keeps_data_dir=True)
        self.set_active(name)
        return name

    def add(self, name: str, grid: OccupancyGrid, floor: str, source: str,
            world_from: Path | None = None) -> MapEntry:
        """Add a new map (refused when the name is taken)."""
        check_name(name)
        floor = check_floor(floor)
        if self.exists(name) or (self.root / name).exists():
            raise MapLibraryError(f"map name {name!r} is taken: choose another name or "
                                  "delete that map first")
        _check_size(grid)
        self._write_new(name, grid, floor, source, world_from)
        return self.entry(name)

    def import_files(self, name: str, yaml_bytes: bytes, image_name: str, image_bytes: bytes,
                     floor: str) -> MapEntry:
        """Add a map_server map from its YAML and image (an upload), validated by loading it
        exactly as the rover would."""
        check_name(name)
        if not re.match(r"^[A-Za-z0-9._-]{1,80}\.(pgm|png)$", image_name, re.I):
            raise MapLibraryError(f"image file name {image_name[:80]!r} is not allowed: "
                                  "a .pgm or .png file")
        staging = self.root / ".upload"
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        try:
            (staging / image_name).write_bytes(image_bytes)
            try:
                meta = _yaml_with_image(yaml_bytes, image_name)
            except ValueError as exc:
                raise MapLibraryError(f"the YAML file is not a map_server map: {exc}") from None
            (staging / "upload.yaml").write_text(meta, encoding="utf-8")
            try:
                grid = load_map(staging / "upload.yaml")
            except MapError as exc:
                text = str(exc).replace(str(staging / "upload.yaml") + ": ", "")
                raise MapLibraryError(f"the map cannot be used: {text}") from None
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return self.add(name, grid, floor, "upload")

    def _write_new(self, name: str, grid: OccupancyGrid, floor: str, source: str,
                   world_from: Path | None, keeps_data_dir: bool = False) -> None:
        staging = self.root / f".new-{name}"
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        save_map(grid, staging / f"{name}.yaml")
        if world_from is not None:
            _copy_world(world_from, staging / "world")
        atomic_write_json(staging / "map.json", {
            "version": FILE_VERSION, "name": name, "floor": floor, "revision": 1,
            "created_wall_s": float(self._wall_time()), "source": source,
            "keeps_data_dir": keeps_data_dir})
        staging.rename(self.root / name)

    # --- changing ----------------------------------------------------------------------------

    def set_floor(self, name: str, floor: str) -> None:
        """Label ``name`` with ``floor``."""
        meta = self.meta(name)
        meta["floor"] = check_floor(floor)
        atomic_write_json(self.root / name / "map.json", meta)

    def rename(self, name: str, new: str) -> None:
        """Rename a map that is not active (its files, revisions and zones go with it)."""
        self._need(name)
        check_name(new)
        if new == name:
            return
        if name == self.active:
            raise MapLibraryError(f"map {name!r} is the active map: switch to another map "
                                  "before renaming it")
        if self.exists(new) or (self.root / new).exists():
            raise MapLibraryError(f"map name {new!r} is taken: choose another name")
        src, dst = self.root / name, self.root / new
        src.rename(dst)
        grid = load_map(dst / f"{name}.yaml")
        save_map(grid, dst / f"{new}.yaml")
        for suffix in (".yaml", ".pgm"):
            (dst / f"{name}{suffix}").unlink(missing_ok=True)
        meta = json.loads((dst / "map.json").read_text(encoding="utf-8"))
        meta["name"] = new
        atomic_write_json(dst / "map.json", meta)
        for suffix in (".json", ".json.bak"):
            zone = self.zones_dir / f"{name}{suffix}"
            if zone.is_file():
                _rename_zone_file(zone, self.zones_dir / f"{new}{suffix}", new)

    def delete(self, name: str) -> None:
        """Delete a map that is not active, with its revisions and zones."""
        self._need(name)
        if name == self.active:
            raise MapLibraryError(f"map {name!r} is the active map and cannot be deleted: "
                                  "switch to another map first")
        trash = self.root / f".deleted-{name}"
        shutil.rmtree(trash, ignore_errors=True)
        (self.root / name).rename(trash)
        shutil.rmtree(trash, ignore_errors=True)
        for suffix in (".json", ".json.bak"):
            (self.zones_dir / f"{name}{suffix}").unlink(missing_ok=True)

    def save_revision(self, name: str, grid: OccupancyGrid,
                      expect_revision: int | None = None) -> int:
        """Keep the current revision under ``revisions/`` and make ``grid`` the new one;
        return its number. ``expect_revision``: refused if another edit came first."""
        meta = self.meta(name)
        current = int(meta.get("revision", 1))
        if expect_revision is not None and expect_revision != current:
            raise MapLibraryError(
                f"map {name!r} is at revision {current}, not {expect_revision}: someone saved "
                "it meanwhile; reload it and edit again")
        _check_size(grid)
        folder = self.root / name
        old = load_map(folder / f"{name}.yaml")
        save_map(old, folder / "revisions" / f"r{current}.yaml")
        save_map(grid, folder / f"{name}.yaml")
        meta["revision"] = current + 1
        atomic_write_json(folder / "map.json", meta)
        return current + 1

    def restore(self, name: str, revision: int) -> int:
        """Make a kept revision the current one again (as a new revision); return its number."""
        if revision not in self.revisions(name):
            kept = ", ".join(str(r) for r in self.revisions(name)) or "none"
            raise MapLibraryError(f"map {name!r} has no kept revision {revision} (kept: {kept})")
        grid = load_map(self.root / name / "revisions" / f"r{revision}.yaml")
        return self.save_revision(name, grid)

    def _need(self, name: str) -> None:
        if not isinstance(name, str) or not _NAME.match(name) or not (
                self.root / name / "map.json").is_file():
            have = ", ".join(self.names()) or "none"
            raise MapLibraryError(f"there is no map {str(name)[:50]!r} (maps: {have})")


def _rename_zone_file(old: Path, new: Path, map_name: str) -> None:
    """Move a zones file, its ``map`` field renamed too (left as it is if unreadable)."""
    try:
        data = json.loads(old.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        old.rename(new)
        return
    if isinstance(data, dict):
        data["map"] = map_name
    atomic_write_json(new, data)
    old.unlink()


def _check_size(grid: OccupancyGrid) -> None:
    if grid.data.size > MAX_CELLS:
        raise MapLibraryError(f"the map has {grid.width} × {grid.height} cells: at most "
                              f"{MAX_CELLS} cells (4096 × 4096) are allowed")


def _yaml_with_image(yaml_bytes: bytes, image_name: str) -> str:
    """The uploaded YAML with its ``image`` pointing at the uploaded image (plain fields only:
    no YAML tags, aliases or a path outside the map)."""
    import yaml

    try:
        meta = yaml.safe_load(yaml_bytes.decode("utf-8"))
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ValueError(f"it is not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(meta, dict) or "image" not in meta:
        raise ValueError("expected a mapping with image, resolution and origin")
    meta["image"] = image_name
    return str(yaml.safe_dump(meta, sort_keys=False))


def _copy_world(map_yaml: Path, folder: Path) -> None:
    """Copy a simulated building (its YAML, image and ``.world.toml``) into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    grid = load_map(map_yaml)
    save_map(grid, folder / map_yaml.name)
    spec = map_yaml.with_name(map_yaml.stem + ".world.toml")
    if spec.is_file():
        atomic_write_bytes(folder / spec.name, spec.read_bytes())
