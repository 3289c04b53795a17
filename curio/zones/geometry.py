"""Polygon geometry for zones (``map``, metres): containment, overlap and distance.

Zones may be concave (any simple polygon); the rover's footprint is small and convex. All
functions are exact for simple polygons and vectorised with numpy over the edges.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["points_in_polygon", "polygon_area", "polygon_distance", "polygons_overlap",
           "self_intersects"]

F64 = npt.NDArray[np.float64]


def polygon_area(poly: F64) -> float:
    """Signed area (shoelace), square metres: positive counter-clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def points_in_polygon(points: F64, poly: F64) -> npt.NDArray[np.bool_]:
    """Even-odd containment of ``(N, 2)`` points in a polygon ``(M, 2)``."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    x, y = pts[:, 0:1], pts[:, 1:2]
    x1, y1 = poly[None, :, 0], poly[None, :, 1]
    nxt = np.roll(poly, -1, axis=0)
    x2, y2 = nxt[None, :, 0], nxt[None, :, 1]
    cond = (y1 > y) != (y2 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
    crosses = cond & (x < xint)
    return np.asarray(crosses.sum(axis=1) % 2 == 1)


def _edges(poly: F64) -> tuple[F64, F64]:
    return poly, np.roll(poly, -1, axis=0)


def _segments_cross(a0: F64, a1: F64, b0: F64, b1: F64) -> npt.NDArray[np.bool_]:
    """Pairwise proper-or-touching intersection of segments a (N) and b (M): ``(N, M)``."""
    def orient(p: F64, q: F64, r: F64) -> F64:
        return np.asarray((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                          - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    A0, A1 = a0[:, None, :], a1[:, None, :]
    B0, B1 = b0[None, :, :], b1[None, :, :]
    d1 = orient(B0, B1, A0)
    d2 = orient(B0, B1, A1)
    d3 = orient(A0, A1, B0)
    d4 = orient(A0, A1, B1)
    return np.asarray((d1 * d2 <= 0.0) & (d3 * d4 <= 0.0)
                      & ~((d1 == 0) & (d2 == 0) & (d3 == 0) & (d4 == 0)))


def polygons_overlap(a: F64, b: F64) -> bool:
    """Whether two simple polygons overlap (an edge crossing, or one inside the other)."""
    a0, a1 = _edges(a)
    b0, b1 = _edges(b)
    if bool(_segments_cross(a0, a1, b0, b1).any()):
        return True
    return bool(points_in_polygon(a[:1], b)[0] or points_in_polygon(b[:1], a)[0])


def _point_segment_distance(p: F64, s0: F64, s1: F64) -> F64:
    """Distance of each point ``(N, 2)`` to each segment ``(M, 2)-(M, 2)``: ``(N, M)``."""
    d = s1 - s0
    ll = np.maximum((d * d).sum(axis=1), 1e-18)
    rel = p[:, None, :] - s0[None, :, :]
    t = np.clip((rel * d[None, :, :]).sum(axis=2) / ll[None, :], 0.0, 1.0)
    closest = s0[None, :, :] + t[..., None] * d[None, :, :]
    return np.asarray(np.hypot(p[:, None, 0] - closest[..., 0], p[:, None, 1] - closest[..., 1]))


def polygon_distance(a: F64, b: F64) -> float:
    """Smallest distance between two simple polygons, metres (0 when they overlap)."""
    if polygons_overlap(a, b):
        return 0.0
    a0, a1 = _edges(a)
    b0, b1 = _edges(b)
    return float(min(_point_segment_distance(a, b0, b1).min(),
                     _point_segment_distance(b, a0, a1).min()))


def self_intersects(poly: F64) -> bool:
    """Whether a polygon's edges cross each other (other than neighbours at their shared
    vertex)."""
    n = len(poly)
    if n < 4:
        return False
    a0, a1 = _edges(poly)
    cross = _segments_cross(a0, a1, a0, a1)
    idx = np.arange(n)
    near = (np.abs(idx[:, None] - idx[None, :]) <= 1) | (
        np.abs(idx[:, None] - idx[None, :]) == n - 1)
    return bool((cross & ~near).any())
