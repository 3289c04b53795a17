"""What goes over the fleet's wire: compact JSON for state, binary for scans and maps.

JSON payloads are UTF-8 objects with ``t`` (the sender's wall clock, UNIX seconds) and SI units
in ``map`` (metres, radians); floats are rounded to millimetres and milliradians
(:func:`dumps`). A rover's scan is thinned to a few dozen beams in centimetres with the laser's
pose in ``map`` (:func:`encode_scan`); a map is a JSON header line and the zlib-compressed
occupancy cells (:func:`encode_map`). :func:`loads` refuses anything that is not a JSON object
(a malformed sample is dropped by the caller, never raised into the loop).
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage, LaserScan

__all__ = [
    "DecodeError",
    "ScanFrame",
    "decode_map",
    "decode_scan",
    "dumps",
    "encode_map",
    "encode_scan",
    "grid_digest",
    "loads",
    "thin_path",
]

_SCAN_MAGIC = b"CS1"
_SCAN_HEAD = struct.Struct("<3sdfffffH")
MAX_JSON_BYTES = 1 << 20


class DecodeError(ValueError):
    """A payload that is not what its key promises."""


def _round(value: Any) -> Any:
    if isinstance(value, float):
        if not math.isfinite(value):
            return None
        return round(value, 3)
    if isinstance(value, dict):
        return {str(k): _round(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_round(v) for v in value]
    return value


def dumps(obj: dict[str, Any]) -> bytes:
    """Compact JSON bytes of ``obj`` (floats to 3 decimals; inf and nan become null)."""
    return json.dumps(_round(obj), separators=(",", ":"), ensure_ascii=False).encode()


def loads(payload: bytes) -> dict[str, Any]:
    """The JSON object in ``payload``.

    Raises:
        DecodeError: too large, not UTF-8 JSON, or not an object.
    """
    if len(payload) > MAX_JSON_BYTES:
        raise DecodeError(f"payload of {len(payload)} bytes is over {MAX_JSON_BYTES}")
    try:
        obj = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DecodeError(f"not JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise DecodeError(f"expected a JSON object, got {type(obj).__name__}")
    return obj


def thin_path(points: list[tuple[float, float]], step_m: float,
              max_points: int = 200) -> list[tuple[float, float]]:
    """Every point at least ``step_m`` from the previous kept one (the last always kept),
    at most ``max_points``."""
    if not points:
        return []
    out = [points[0]]
    for p in points[1:-1]:
        if math.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) >= step_m:
            out.append(p)
            if len(out) >= max_points - 1:
                break
    if len(points) > 1:
        out.append(points[-1])
    return out


@dataclass(frozen=True)
class ScanFrame:
    """A thinned scan: the laser's pose in ``map`` and its beams.

    Attributes:
        wall_s: when it was taken (sender's wall clock).
        laser: the ``laser`` frame in ``map``.
        angle_min_rad, angle_increment_rad: beam ``i`` is at ``angle_min + i * increment``.
        ranges_m: one per beam; ``inf`` for no return.
    """

    wall_s: float
    laser: Pose2D
    angle_min_rad: float
    angle_increment_rad: float
    ranges_m: npt.NDArray[np.float32]

    def points(self) -> npt.NDArray[np.float64]:
        """The returns in ``map``, ``(N, 2)`` metres."""
        r = self.ranges_m.astype(np.float64)
        ok = np.isfinite(r)
        ang = self.angle_min_rad + np.arange(len(r)) * self.angle_increment_rad
        pts = np.stack([r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])], axis=1)
        return self.laser.transform_points(pts)


def encode_scan(scan: LaserScan, laser_in_map: Pose2D, wall_s: float, beams: int) -> bytes:
    """``scan`` thinned to ``beams`` evenly spaced beams (the nearest return of each sector),
    centimetres as uint16 (0 = no return), with the laser's pose in ``map``."""
    r = np.asarray(scan.ranges_m, dtype=np.float64)
    valid = scan.valid_mask()
    r = np.where(valid, r, np.inf)
    n = len(r)
    beams = max(1, min(beams, n))
    edges = np.linspace(0, n, beams + 1).astype(np.int64)
    mins = np.minimum.reduceat(r, edges[:-1])
    cm = np.where(np.isfinite(mins), np.clip(np.round(mins * 100.0), 1, 65535), 0)
    inc = scan.angle_increment_rad * n / beams
    start = scan.angle_min_rad + 0.5 * (inc - scan.angle_increment_rad)
    head = _SCAN_HEAD.pack(_SCAN_MAGIC, wall_s, laser_in_map.x, laser_in_map.y,
                           laser_in_map.yaw, start, inc, beams)
    return head + cm.astype("<u2").tobytes()


def decode_scan(payload: bytes) -> ScanFrame:
    """The :class:`ScanFrame` of :func:`encode_scan`'s bytes.

    Raises:
        DecodeError: not a scan of this format.
    """
    size = _SCAN_HEAD.size
    if len(payload) < size:
        raise DecodeError("scan payload too short")
    magic, wall_s, x, y, yaw, start, inc, beams = _SCAN_HEAD.unpack_from(payload)
    if magic != _SCAN_MAGIC or len(payload) != size + 2 * beams:
        raise DecodeError("not a Curio scan frame")
    cm = np.frombuffer(payload, dtype="<u2", offset=size, count=beams).astype(np.float32)
    ranges = np.where(cm > 0, cm / 100.0, np.inf).astype(np.float32)
    return ScanFrame(wall_s, Pose2D(x, y, yaw), start, inc, ranges)


def grid_digest(data: npt.NDArray[np.int8]) -> str:
    """A short fingerprint of a grid's cells (maps are compared by it across the fleet)."""
    return hashlib.sha256(np.ascontiguousarray(data).tobytes()).hexdigest()[:16]


def encode_map(grid: GridMessage) -> bytes:
    """A JSON header line (size, resolution, origin, version, digest) and the zlib'd cells."""
    h, w = grid.data.shape
    head = {"w": w, "h": h, "res": grid.resolution_m, "ox": grid.origin.x, "oy": grid.origin.y,
            "oyaw": grid.origin.yaw, "version": grid.version, "kind": grid.kind,
            "sha": grid_digest(grid.data)}
    body = zlib.compress(np.ascontiguousarray(grid.data, dtype=np.int8).tobytes(), 6)
    return json.dumps(head, separators=(",", ":")).encode() + b"\n" + body


def decode_map(payload: bytes, stamp: float = 0.0) -> GridMessage:
    """The :class:`GridMessage` of :func:`encode_map`'s bytes.

    Raises:
        DecodeError: not a map of this format.
    """
    head_bytes, sep, body = payload.partition(b"\n")
    if not sep:
        raise DecodeError("map payload has no header line")
    head = loads(head_bytes)
    try:
        w, h = int(head["w"]), int(head["h"])
        cells = np.frombuffer(zlib.decompress(body), dtype=np.int8)
        data = cells.reshape(h, w).copy()
        origin = Pose2D(float(head["ox"]), float(head["oy"]), float(head["oyaw"]))
        return GridMessage(stamp, data, float(head["res"]), origin,
                           int(head.get("version", 0)), str(head.get("kind", "map")))
    except (KeyError, ValueError, zlib.error) as exc:
        raise DecodeError(f"bad map payload: {exc}") from None
