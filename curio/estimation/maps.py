"""ROS map_server maps: read and write YAML + PGM/PNG, and the in-memory occupancy grid.

The grid follows map_server after loading: ``data[row, col]`` with row 0 at the *bottom* of the
image (lowest y), values −1 unknown, 0 free … 100 occupied. Cell (0, 0)'s lower-left corner is
at ``origin`` in ``map``; ``origin.yaw`` rotates the grid about that corner.

Supported YAML fields: ``image``, ``resolution``, ``origin`` ``[x, y, yaw]``, ``negate``,
``occupied_thresh``, ``free_thresh``, ``mode`` (``trinary`` | ``scale`` | ``raw``). Every
problem raises :class:`MapError` naming the file, the field and what is wrong.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml
from PIL import Image

from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_bytes, atomic_write_text
from curio.core.geometry import Pose2D

__all__ = ["MapError", "OccupancyGrid", "load_map", "map_stats", "save_map"]

UNKNOWN = -1
FREE = 0
OCCUPIED = 100


class MapError(SetupError, ValueError):
    """A map file that cannot be used, with the file, the field and the problem."""


@dataclass(eq=False)
class OccupancyGrid:
    """An occupancy grid in ``map``.

    Attributes:
        data: ``(height, width)`` int8, row 0 at the bottom; −1 unknown, 0..100 occupancy.
        resolution_m: cell size in metres.
        origin: pose of cell (0, 0)'s lower-left corner in ``map``.
        occupied_thresh: occupancy (0..1) at or above which a cell is an obstacle.
        free_thresh: occupancy (0..1) at or below which a cell is free.
        name: where it came from (file name) for messages.
    """

    data: npt.NDArray[np.int8]
    resolution_m: float
    origin: Pose2D = field(default_factory=Pose2D)
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196
    name: str = ""

    @property
    def height(self) -> int:
        """Rows (cells along y)."""
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        """Columns (cells along x)."""
        return int(self.data.shape[1])

    @property
    def size_m(self) -> tuple[float, float]:
        """Extent (width, height) in metres."""
        return (self.width * self.resolution_m, self.height * self.resolution_m)

    def occupied_mask(self) -> npt.NDArray[np.bool_]:
        """Cells that are obstacles."""
        return self.data >= round(self.occupied_thresh * 100)

    def free_mask(self) -> npt.NDArray[np.bool_]:
        """Cells known to be free."""
        return (self.data >= 0) & (self.data <= round(self.free_thresh * 100))

    def unknown_mask(self) -> npt.NDArray[np.bool_]:
        """Cells of unknown occupancy."""
        return self.data < 0

    def edge_mask(self) -> npt.NDArray[np.bool_]:
        """The outermost ring of cells: where the map ends.

        Nothing is known beyond the grid, and a footprint that leaves it cannot be checked, so
        whoever plans or walks on the map treats its edge as a wall (a map drawn without
        border walls, e.g. an open field of shapes, would otherwise offer goals at its rim).
        """
        edge = np.zeros(self.data.shape, dtype=bool)
        edge[[0, -1], :] = True
        edge[:, [0, -1]] = True
        return edge

    def world_to_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """Return ``(row, col)`` of the cell containing map point (x, y) (may be outside)."""
        lx, ly = self.origin.inverse().transform_point(x_m, y_m)
        return (math.floor(ly / self.resolution_m), math.floor(lx / self.resolution_m))

    def world_to_cells(self, xy_m: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
        """Vectorised :meth:`world_to_cell`: ``(N, 2)`` points → ``(N, 2)`` ``(row, col)``."""
        local = self.origin.inverse().transform_points(xy_m)
        cells = np.floor(local[:, ::-1] / self.resolution_m)
        return cells.astype(np.int64)

    def cell_to_world(self, row: int, col: int) -> tuple[float, float]:
        """Return the map coordinates of the centre of cell ``(row, col)``."""
        return self.origin.transform_point((col + 0.5) * self.resolution_m,
                                           (row + 0.5) * self.resolution_m)

    def in_bounds(self, row: int, col: int) -> bool:
        """Whether ``(row, col)`` lies inside the grid."""
        return 0 <= row < self.height and 0 <= col < self.width

    def copy(self) -> OccupancyGrid:
        """A deep copy."""
        return OccupancyGrid(self.data.copy(), self.resolution_m, self.origin,
                             self.occupied_thresh, self.free_thresh, self.name)


def _field(meta: dict[str, Any], key: str, path: Path, kind: type | tuple[type, ...]) -> Any:
    if key not in meta:
        raise MapError(f"{path}: required field '{key}' is missing")
    value = meta[key]
    if isinstance(value, bool) or not isinstance(value, kind):
        raise MapError(f"{path}: field '{key}' has {value!r}, which is not a "
                       f"{getattr(kind, '__name__', 'number')}")
    return value


def _number(meta: dict[str, Any], key: str, path: Path, default: float) -> float:
    """An optional finite number field."""
    value = meta.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MapError(f"{path}: field '{key}' must be a finite number, got {value!r}")
    return float(value)


def load_map(yaml_path: Path | str) -> OccupancyGrid:
    """Load a map_server map (YAML + image).

    Raises:
        MapError: the file, the field and the problem (missing file, bad YAML, bad field,
            unreadable image, inconsistent thresholds).
    """
    path = Path(yaml_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MapError(f"{path}: map file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MapError(f"{path}: cannot read the map file ({exc})") from None
    try:
        meta = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise MapError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(meta, dict):
        raise MapError(f"{path}: expected a YAML mapping with image, resolution and origin")

    image_name = _field(meta, "image", path, str)
    if not image_name.strip():
        raise MapError(f"{path}: field 'image' is empty; it must name a PGM or PNG file")
    resolution = float(_field(meta, "resolution", path, (int, float)))
    if not (math.isfinite(resolution) and resolution > 0):
        raise MapError(f"{path}: field 'resolution' must be > 0 metres per cell, got {resolution}")
    origin = _field(meta, "origin", path, list)
    if len(origin) != 3 or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        for v in origin
    ):
        raise MapError(f"{path}: field 'origin' must be [x, y, yaw] (three finite numbers), "
                       f"got {origin}")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapError(f"{path}: field 'negate' must be 0 or 1, got {negate!r}")
    occ = _number(meta, "occupied_thresh", path, 0.65)
    free = _number(meta, "free_thresh", path, 0.196)
    if not (0.0 <= free < occ <= 1.0):
        raise MapError(f"{path}: thresholds must satisfy 0 <= free_thresh < occupied_thresh <= 1,"
                       f" got free_thresh={free}, occupied_thresh={occ}")
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise MapError(f"{path}: field 'mode' must be trinary, scale or raw, got {mode!r}")

    image_path = Path(image_name)
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    try:
        with Image.open(image_path) as img:
            img.load()
            pixels = _to_gray(img)
            alpha = _alpha(img)
    except FileNotFoundError:
        raise MapError(f"{path}: field 'image' names {image_path}, which does not exist") from None
    except (OSError, ValueError) as exc:
        raise MapError(f"{path}: field 'image': cannot read {image_path} ({exc})") from None
    if pixels.size == 0:
        raise MapError(f"{path}: field 'image': {image_path} has no pixels")

    data = _pixels_to_occupancy(pixels, mode, bool(negate), occ, free)
    if mode == "raw":
        bad = (data > 100) & (data != 255)
        if bad.any():
            r, c = (int(v[0]) for v in np.nonzero(bad))
            raise MapError(f"{path}: field 'mode' is raw, but {image_path.name} has pixel value "
                           f"{int(data[r, c])} at row {r}, column {c}; raw maps hold 0..100 "
                           "(occupancy) or 255 (unknown)")
        data = np.where(data == 255, UNKNOWN, data)
    elif mode == "scale" and alpha is not None:
        data = np.where(alpha < 255, UNKNOWN, data)  # map_server: transparent = unknown
    return OccupancyGrid(
        data=np.ascontiguousarray(data[::-1].astype(np.int8)),
        resolution_m=resolution,
        origin=Pose2D(float(origin[0]), float(origin[1]), float(origin[2])),
        occupied_thresh=occ,
        free_thresh=free,
        name=path.name,
    )


def _alpha(img: Image.Image) -> npt.NDArray[np.uint8] | None:
    """The alpha channel, if the image has one."""
    if img.mode in ("RGBA", "LA") or (img.mode == "P" and "transparency" in img.info):
        return np.asarray(img.convert("RGBA"), dtype=np.uint8)[:, :, 3]
    return None


def _to_gray(img: Image.Image) -> npt.NDArray[np.float64]:
    """Image → float array 0..255 (colour averaged as map_server does; alpha ignored)."""
    if img.mode in ("I;16", "I;16B", "I;16L", "I"):
        arr = np.asarray(img, dtype=np.float64)
        return arr * (255.0 / max(1.0, float(arr.max()))) if arr.max() > 255 else arr
    if img.mode not in ("L", "RGB", "RGBA", "LA", "P", "1"):
        raise ValueError(f"unsupported image mode {img.mode}")
    if img.mode in ("RGB", "RGBA", "P"):
        rgb = np.asarray(img.convert("RGB"), dtype=np.float64)
        return np.asarray(rgb.mean(axis=2))
    return np.asarray(img.convert("L"), dtype=np.float64)


def _pixels_to_occupancy(
    pixels: npt.NDArray[np.float64], mode: str, negate: bool, occ: float, free: float
) -> npt.NDArray[np.int16]:
    """map_server's conversion; raw mode returns the pixel values (checked by the caller)."""
    if mode == "raw":
        value = 255.0 - pixels if negate else pixels
        return np.rint(value).astype(np.int16)
    p = pixels / 255.0 if negate else (255.0 - pixels) / 255.0
    out = np.full(pixels.shape, UNKNOWN, dtype=np.int16)
    out[p > occ] = OCCUPIED
    out[p < free] = FREE
    if mode == "scale":
        mid = (p >= free) & (p <= occ)
        out[mid] = np.rint(99.0 * (p[mid] - free) / (occ - free)).astype(np.int16)
    return out


def save_map(grid: OccupancyGrid, yaml_path: Path | str, image_format: str = "pgm",
             mode: str = "trinary") -> Path:
    """Write ``grid`` as a map_server map (YAML + PGM or PNG), atomically; return the YAML path.

    Modes: ``trinary`` (free 254, occupied 0, unknown 205, as map_saver does), ``scale``
    (occupancy p written as ``255 − p·255/100``, unknown 205) and ``raw`` (the values 0..100
    themselves, unknown 255). The image sits beside the YAML with the same stem.
    """
    path = Path(yaml_path)
    if image_format not in ("pgm", "png"):
        raise MapError(f"{path}: image format must be pgm or png, got {image_format!r}")
    if mode not in ("trinary", "scale", "raw"):
        raise MapError(f"{path}: mode must be trinary, scale or raw, got {mode!r}")
    image_path = path.with_suffix("." + image_format)
    data = grid.data.astype(np.int16)
    if mode == "trinary":
        pixels = np.full(grid.data.shape, 205, dtype=np.uint8)
        pixels[grid.free_mask()] = 254
        pixels[grid.occupied_mask()] = 0
    elif mode == "scale":
        # The inverse of map_server's scale mode: 0 → 254, 100 → 0, 1..99 → the grey whose
        # occupancy falls at that point between free_thresh and occupied_thresh. Unknown cells
        # are transparent, which only PNG can store.
        unknown = data < 0
        if unknown.any() and image_format != "png":
            raise MapError(f"{path}: scale mode marks unknown cells as transparent; "
                           f"{int(unknown.sum())} unknown cells need image format png")
        lo, hi = grid.free_thresh, grid.occupied_thresh
        occ = lo + np.clip(data, 0, 100) / 99.0 * (hi - lo)
        exact = 255.0 * (1.0 - occ)
        pixels = np.floor(exact + 0.5)
        for candidate in (np.floor(exact), np.ceil(exact)):  # the grey that decodes back
            back = _pixels_to_occupancy(candidate, "scale", False, hi, lo)
            pixels = np.where(back == data, candidate, pixels)
        pixels = np.clip(pixels, 0, 255).astype(np.uint8)
        pixels[data <= 0] = 254
        pixels[data >= 100] = 0
        if unknown.any():
            alpha = np.where(unknown, 0, 255).astype(np.uint8)
            la = np.stack([pixels[::-1], alpha[::-1]], axis=2)
            buf = io.BytesIO()
            Image.fromarray(np.ascontiguousarray(la), mode="LA").save(buf, format="PNG")
            atomic_write_bytes(image_path, buf.getvalue())
            return _write_yaml(grid, path, image_path, mode)
    else:
        pixels = np.where(data < 0, 255, np.clip(data, 0, 100)).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels[::-1]), mode="L").save(
        buf, format="PPM" if image_format == "pgm" else "PNG"
    )
    atomic_write_bytes(image_path, buf.getvalue())
    return _write_yaml(grid, path, image_path, mode)


def _write_yaml(grid: OccupancyGrid, path: Path, image_path: Path, mode: str) -> Path:
    meta = (
        f"image: {image_path.name}\n"
        f"mode: {mode}\n"
        f"resolution: {float(grid.resolution_m)!r}\n"
        f"origin: [{float(grid.origin.x)!r}, {float(grid.origin.y)!r}, "
        f"{float(grid.origin.yaw)!r}]\n"
        f"negate: 0\n"
        f"occupied_thresh: {float(grid.occupied_thresh)!r}\n"
        f"free_thresh: {float(grid.free_thresh)!r}\n"
    )
    atomic_write_text(path, meta)
    return path


def map_stats(grid: OccupancyGrid) -> dict[str, float]:
    """Size and content of a grid: cells, metres, and free / occupied / unknown percentages."""
    n = max(1, grid.data.size)
    return {
        "width_cells": float(grid.width),
        "height_cells": float(grid.height),
        "width_m": grid.size_m[0],
        "height_m": grid.size_m[1],
        "resolution_m": grid.resolution_m,
        "free_pct": 100.0 * float(np.count_nonzero(grid.free_mask())) / n,
        "occupied_pct": 100.0 * float(np.count_nonzero(grid.occupied_mask())) / n,
        "unknown_pct": 100.0 * float(np.count_nonzero(grid.unknown_mask())) / n,
    }
