"""Wire formats of the dashboard: compact binary frames, grid PNGs and JSON-safe dicts.

Binary WebSocket frames (little-endian) start with a 16-byte header::

    uint8 type | 7 bytes padding | float64 stamp_s

then, by type:

* ``FRAME_SCAN`` (1): ``float32 laser_x_m, laser_y_m, laser_yaw_rad`` (the laser's pose in
  ``map``, resolved on the server so the browser never walks a frame tree),
  ``float32 angle_min_rad, angle_increment_rad``, ``uint32 n``, then ``n`` × ``uint16`` ranges
  in millimetres (0 = no valid return).
* ``FRAME_POSE`` (2) and ``FRAME_TRUTH`` (5): ``float32 x_m, y_m, yaw_rad, std_x_m, std_y_m,
  std_yaw_rad`` in ``map``.
* ``FRAME_PLAN`` (3) and ``FRAME_LOCAL_PLAN`` (4): ``uint32 n`` then ``n`` × ``float32 (x_m,
  y_m)`` in ``map``.

Grids become PNGs (lossless: JPEG smears walls) with the top image row at the largest ``y``.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import struct
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image

from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage, LaserScan, Odometry, Path, PoseWithCovariance

__all__ = [
    "FRAME_LOCAL_PLAN",
    "FRAME_PLAN",
    "FRAME_POSE",
    "FRAME_SCAN",
    "FRAME_TRUTH",
    "decode_frame",
    "encode_path",
    "encode_pose",
    "encode_scan",
    "grid_meta",
    "grid_png",
    "path_to_json",
]

FRAME_SCAN = 1
FRAME_POSE = 2
FRAME_PLAN = 3
FRAME_LOCAL_PLAN = 4
FRAME_TRUTH = 5

_HEADER = struct.Struct("<B7xd")
_SCAN_HEAD = struct.Struct("<fffffI")
_POSE = struct.Struct("<ffffff")
_COUNT = struct.Struct("<I")
# Largest range a uint16 in millimetres can carry (65.534 m); longer ranges count as invalid.
_MAX_MM = 65534


def _std(cov: tuple[float, ...], i: int) -> float:
    if len(cov) != 9:
        return 0.0
    value = cov[4 * i]
    return math.sqrt(value) if value > 0.0 and math.isfinite(value) else 0.0


def encode_scan(scan: LaserScan, laser_in_map: Pose2D) -> bytes:
    """Pack ``scan`` as a ``FRAME_SCAN`` frame; ``laser_in_map`` is the laser's pose in map."""
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    valid = scan.valid_mask()
    mm = np.zeros(ranges.shape, dtype=np.uint16)
    with np.errstate(invalid="ignore"):
        ok = valid & (ranges * 1000.0 <= _MAX_MM) & (ranges > 0.0)
    mm[ok] = np.maximum(1, np.rint(ranges[ok] * 1000.0)).astype(np.uint16)
    head = _HEADER.pack(FRAME_SCAN, scan.stamp) + _SCAN_HEAD.pack(
        laser_in_map.x,
        laser_in_map.y,
        laser_in_map.yaw,
        scan.angle_min_rad,
        scan.angle_increment_rad,
        len(mm),
    )
    return head + mm.astype("<u2").tobytes()


def encode_pose(
    msg: PoseWithCovariance | Odometry, frame_type: int = FRAME_POSE
) -> bytes:
    """Pack a pose (and the standard deviations from its covariance) as a pose frame."""
    p = msg.pose
    cov = msg.covariance
    return _HEADER.pack(frame_type, msg.stamp) + _POSE.pack(
        p.x, p.y, p.yaw, _std(cov, 0), _std(cov, 1), _std(cov, 2)
    )


def encode_path(path: Path, frame_type: int = FRAME_PLAN) -> bytes:
    """Pack the positions of ``path`` (map, metres) as a path frame."""
    xy = np.array([(p.x, p.y) for p in path.poses], dtype="<f4").reshape(-1, 2)
    return _HEADER.pack(frame_type, path.stamp) + _COUNT.pack(len(xy)) + xy.tobytes()


def decode_frame(data: bytes) -> dict[str, Any]:
    """Unpack a binary frame into a dict (used by tests and tools; the browser has its own)."""
    frame_type, stamp = _HEADER.unpack_from(data, 0)
    off = _HEADER.size
    out: dict[str, Any] = {"type": frame_type, "stamp": stamp}
    if frame_type == FRAME_SCAN:
        lx, ly, lyaw, amin, ainc, n = _SCAN_HEAD.unpack_from(data, off)
        off += _SCAN_HEAD.size
        mm = np.frombuffer(data, dtype="<u2", count=n, offset=off)
        out.update(laser=(lx, ly, lyaw), angle_min=amin, angle_increment=ainc,
                   ranges_mm=mm.tolist())
    elif frame_type in (FRAME_POSE, FRAME_TRUTH):
        x, y, yaw, sx, sy, syaw = _POSE.unpack_from(data, off)
        out.update(x=x, y=y, yaw=yaw, std=(sx, sy, syaw))
    elif frame_type in (FRAME_PLAN, FRAME_LOCAL_PLAN):
        (n,) = _COUNT.unpack_from(data, off)
        xy = np.frombuffer(data, dtype="<f4", count=2 * n, offset=off + _COUNT.size)
        out["points"] = xy.reshape(-1, 2).tolist()
    else:
        raise ValueError(f"unknown frame type {frame_type}")
    return out


def _map_rgba(data: npt.NDArray[np.int8]) -> npt.NDArray[np.uint8]:
    """Occupancy → grey image like RViz's "map" scheme: free white, occupied black."""
    d = data.astype(np.int16)
    grey = np.where(d < 0, 205, 254 - (np.clip(d, 0, 100) * 254) // 100).astype(np.uint8)
    rgba = np.empty((*d.shape, 4), dtype=np.uint8)
    rgba[..., 0] = grey
    rgba[..., 1] = grey
    rgba[..., 2] = grey
    rgba[..., 3] = 255
    return rgba


def _costmap_rgba(data: npt.NDArray[np.int8]) -> npt.NDArray[np.uint8]:
    """Costs → a translucent overlay: free transparent, inflation blue→magenta, lethal red."""
    d = np.clip(data.astype(np.int16), -1, 100)
    rgba = np.zeros((*d.shape, 4), dtype=np.uint8)
    cost = np.clip(d, 0, 100)
    lethal = d >= 99
    mid = (d > 0) & ~lethal
    rgba[mid, 0] = (cost[mid] * 2.2).astype(np.uint8)
    rgba[mid, 1] = 40
    rgba[mid, 2] = 230
    rgba[mid, 3] = (40 + cost[mid] * 1.4).astype(np.uint8)
    rgba[lethal] = (230, 20, 40, 200)
    return rgba


def grid_png(grid: GridMessage) -> bytes:
    """Encode ``grid`` as a PNG, the top row at the largest y (row 0 of the grid is the bottom).

    Maps (``kind == "map"``) use a grey scheme; costmaps a translucent colour overlay.
    """
    data = np.asarray(grid.data, dtype=np.int8)
    if data.ndim != 2 or data.size == 0:
        raise ValueError(f"grid must be a non-empty 2-D array, got shape {data.shape}")
    rgba = _map_rgba(data) if grid.kind == "map" else _costmap_rgba(data)
    image = Image.fromarray(np.ascontiguousarray(rgba[::-1]), mode="RGBA")
    buf = io.BytesIO()
    image.save(buf, format="PNG", optimize=False, compress_level=6)
    return buf.getvalue()


def grid_meta(grid: GridMessage) -> dict[str, Any]:
    """Geometry of ``grid`` for the browser: size in cells, metres per cell, origin in map."""
    height, width = grid.data.shape
    return {
        "width": int(width),
        "height": int(height),
        "resolution_m": float(grid.resolution_m),
        "origin": [grid.origin.x, grid.origin.y, grid.origin.yaw],
        "kind": grid.kind,
        "frame_id": grid.frame_id,
    }


def path_to_json(path: Any) -> dict[str, Any]:
    """A path manager ``NamedPath`` as JSON data (waypoints in map, metres and radians) with
    ``rev``, a short hash of its content: an edit sent with an older ``rev`` is refused, so
    two operators cannot silently overwrite each other's changes."""
    waypoints = [{"x_m": float(w.x_m), "y_m": float(w.y_m),
                  "yaw_rad": None if w.yaw_rad is None else float(w.yaw_rad)}
                 for w in path.waypoints]
    content = json.dumps([path.name, waypoints], sort_keys=True).encode()
    return {"id": path.id, "name": path.name, "waypoints": waypoints,
            "rev": hashlib.sha1(content).hexdigest()[:12]}
