"""Compiled stop-zone geometry (numba, ``nogil``): signed polygon distances and the sweep.

All coordinates are metres in ``base_link`` (x forward, y left). A polygon is an ``(E, 2)``
array of vertices in either orientation; the signed distance of a point is its distance to the
nearest edge, negative inside (crossing-number test). The sweep moves the scan points into the
rover's frame at each predicted pose of the commanded arc and reduces, per point, what
:meth:`curio.safety.stage.StopZone.evaluate` needs — with the same arithmetic as the former numpy
version, so the results are the same.

The first call compiles the kernels (a few seconds); numba caches the machine code on disk.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["polygon_distances_into", "sweep_stop_zone"]

F64 = npt.NDArray[np.float64]


@njit(cache=True, nogil=True, inline="always")  # type: ignore[misc]
def _signed_distance(px: float, py: float, poly: F64) -> float:  # pragma: no cover - compiled
    """Signed distance (m) from ``(px, py)`` to the boundary of ``poly``; NaN if any edge's is."""
    n_edges = poly.shape[0]
    best = math.inf
    nan_seen = False
    crossings = 0
    for i in range(n_edges):
        ax = poly[i, 0]
        ay = poly[i, 1]
        j = i + 1 if i + 1 < n_edges else 0
        bx = poly[j, 0]
        by = poly[j, 1]
        abx = bx - ax
        aby = by - ay
        apx = px - ax
        apy = py - ay
        denom = max(abx * abx + aby * aby, 1e-12)
        t = (apx * abx + apy * aby) / denom
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
        ex = px - (ax + t * abx)
        ey = py - (ay + t * aby)
        d = math.sqrt(ex * ex + ey * ey)
        if d < best:
            best = d
        elif d != d:
            nan_seen = True
        # Crossing number: the edge straddles the point's row and crosses it to the right.
        if (ay > py) != (by > py):
            xint = ax + (py - ay) * (bx - ax) / (by - ay)
            if px < xint:
                crossings += 1
    if nan_seen:
        best = math.nan
    return -best if crossings % 2 == 1 else best


@njit(cache=True, nogil=True)  # type: ignore[misc]
def polygon_distances_into(points: F64, poly: F64,
                           out: F64) -> None:  # pragma: no cover - compiled
    """Signed distance (m) of each of ``points`` ``(N, 2)`` to ``poly`` into ``out`` ``(N,)``."""
    for k in range(points.shape[0]):
        out[k] = _signed_distance(points[k, 0], points[k, 1], poly)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def sweep_stop_zone(
    points: F64, reach_m: float, poses: F64, cos_yaw: F64, sin_yaw: F64, footprint: F64,
    stop_poly: F64, slow_poly: F64, use_slow: bool, contact_margin_m: float,
) -> tuple[bool, float, int, float]:  # pragma: no cover - compiled
    """Sweep the footprint along the predicted poses against the scan points.

    Args:
        points: ``(N, 2)`` scan points in ``base_link``, metres.
        reach_m: only points nearer the origin than this count.
        poses: ``(K, 3)`` predicted poses ``(x, y, yaw)`` in the start pose's frame
            (``poses[0]`` is the start).
        cos_yaw, sin_yaw: ``(K,)`` cosine and sine of the poses' yaws.
        footprint: ``(E, 2)`` footprint; points inside it at the start are ignored.
        stop_poly: the footprint extended by the stop margin in the direction of travel.
        slow_poly: the same for the slow margin (only used when ``use_slow``).
        contact_margin_m: an approached point nearer than this to ``stop_poly`` is a hit.

    A point is *approached* at step ``k ≥ 1`` when its distance to ``stop_poly`` there is
    more than 0.1 mm smaller than at the start.

    Returns:
        ``(approached, clearance_m, first_hit, slow_near_m)``: whether any point is approached;
        the smallest distance of an approached point (m); the first step ``k - 1`` (0-based
        over the steps after the start) with a hit, −1 if none; the smallest distance of an
        approached point inside ``slow_poly`` (m, ``inf`` if none or not ``use_slow``).
    """
    n_steps = poses.shape[0]
    approached = False
    clearance = math.inf
    first_hit = -1
    slow_near = math.inf
    for i in range(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        if not math.hypot(px, py) < reach_m:
            continue
        # The start pose: points inside the footprint are self-hits or already touching.
        dx = px - poses[0, 0]
        dy = py - poses[0, 1]
        lx = cos_yaw[0] * dx + sin_yaw[0] * dy
        ly = -sin_yaw[0] * dx + cos_yaw[0] * dy
        if not _signed_distance(lx, ly, footprint) > 0.0:
            continue
        d0 = _signed_distance(lx, ly, stop_poly)
        for k in range(1, n_steps):
            dx = px - poses[k, 0]
            dy = py - poses[k, 1]
            lx = cos_yaw[k] * dx + sin_yaw[k] * dy
            ly = -sin_yaw[k] * dx + cos_yaw[k] * dy
            d = _signed_distance(lx, ly, stop_poly)
            if not d < d0 - 1e-4:
                continue
            approached = True
            if d < clearance:
                clearance = d
            if d < contact_margin_m and (first_hit < 0 or k - 1 < first_hit):
                first_hit = k - 1
            if use_slow and d < slow_near and _signed_distance(lx, ly, slow_poly) < 0.0:
                slow_near = d
    return approached, clearance, first_hit, slow_near
