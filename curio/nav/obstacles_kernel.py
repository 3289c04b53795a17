"""Compiled obstacle extraction (numba, ``nogil``): grouping, split-and-merge and fitting.

The kernel takes one scan's valid points already transformed into ``map`` (metres, in beam
order) and returns the segments and circles that :class:`curio.nav.obstacles.ObstacleExtractor`
publishes, in the same order and with the same results as its former numpy version (to
rounding: sums here are sequential):

* neighbouring points belong to one group while they are closer than
  ``group_distance_m + distance_proportion · max(range_i, range_i+1)`` and at most one beam is
  missing between them; on a full revolution the last group may continue into the first;
* a group of ``min_group_points`` or more whose extent (chord, twice its spread about the
  centroid) is below ``2 · max_circle_radius_m`` becomes one circle pushed away from the sensor;
* other groups are split (iterative end-point fit) until every point is within
  ``split_distance_m`` of its piece's chord; each piece gets a least-squares segment, and
  pieces shorter than ``2 · max_circle_radius_m`` become circles.

The first call compiles it (a few seconds); numba caches the machine code on disk.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["extract_obstacles"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

_SQRT3 = math.sqrt(3.0)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _fit_piece(x: F64, y: F64, s: int, e: int,
               out: F64) -> None:  # pragma: no cover - compiled
    """Least-squares segment through points ``s..e-1``, clipped to their extent.

    Writes ``(x1, y1, x2, y2)`` into ``out`` with the first end nearer the piece's first point.
    """
    m = e - s
    cx = 0.0
    cy = 0.0
    for j in range(s, e):
        cx += x[j]
        cy += y[j]
    cx /= m
    cy /= m
    sxx = 0.0
    syy = 0.0
    sxy = 0.0
    for j in range(s, e):
        dx = x[j] - cx
        dy = y[j] - cy
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    # Principal axis of the 2x2 scatter matrix in closed form (what an SVD would give).
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    ux = math.cos(theta)
    uy = math.sin(theta)
    tmin = math.inf
    tmax = -math.inf
    for j in range(s, e):
        t = (x[j] - cx) * ux + (y[j] - cy) * uy
        if t < tmin:
            tmin = t
        if t > tmax:
            tmax = t
    x1 = cx + ux * tmin
    y1 = cy + uy * tmin
    x2 = cx + ux * tmax
    y2 = cy + uy * tmax
    # Keep the scan's order (first end near the first beam).
    if math.hypot(x1 - x[s], y1 - y[s]) > math.hypot(x2 - x[s], y2 - y[s]):
        x1, y1, x2, y2 = x2, y2, x1, y1
    out[0] = x1
    out[1] = y1
    out[2] = x2
    out[3] = y2


@njit(cache=True, nogil=True)  # type: ignore[misc]
def extract_obstacles(
    x: F64, y: F64, ranges_m: F64, beam_idx: I64, n_beams: int, sensor_x: float,
    sensor_y: float, group_distance_m: float, distance_proportion: float,
    min_group_points: int, split_distance_m: float, max_circle_radius_m: float,
    radius_enlargement_m: float,
) -> tuple[F64, F64]:  # pragma: no cover - compiled
    """Segments and circles of one scan (see the module docstring).

    Args:
        x, y: ``(N,)`` the valid beams' end points in ``map``, metres, in beam order.
        ranges_m: ``(N,)`` their ranges, metres.
        beam_idx: ``(N,)`` their beam indices (increasing) in a scan of ``n_beams`` beams.
        sensor_x, sensor_y: the lidar's position in ``map``, metres.
        group_distance_m … radius_enlargement_m: the ``nav.blocked`` extraction keys.

    Returns:
        ``segments (S, 4)`` rows ``(x1, y1, x2, y2)`` and ``circles (C, 3)`` rows
        ``(x, y, radius)``, metres, in ``map``.
    """
    n = x.shape[0]
    segments = np.empty((max(n, 1), 4))
    circles = np.empty((max(n, 1), 3))
    n_seg = 0
    n_circ = 0
    if n == 0:
        return segments[:0], circles[:0]
    # Groups: break where neighbours are far apart (or beams are missing in between).
    bounds = np.empty(n + 1, dtype=np.int64)  # group g spans bounds[g] .. bounds[g+1]-1
    bounds[0] = 0
    n_groups = 0
    for i in range(n - 1):
        gap = math.hypot(x[i + 1] - x[i], y[i + 1] - y[i])
        thr = group_distance_m + distance_proportion * max(ranges_m[i], ranges_m[i + 1])
        if gap > thr or beam_idx[i + 1] - beam_idx[i] > 2:
            n_groups += 1
            bounds[n_groups] = i + 1
    n_groups += 1
    bounds[n_groups] = n
    # A full revolution: the last group may continue into the first. Rotating the points so
    # the last group comes first makes the merged group the first one, as before.
    gx = x
    gy = y
    if n_groups > 1 and beam_idx[0] == 0 and beam_idx[n - 1] == n_beams - 1 and \
            math.hypot(x[n - 1] - x[0], y[n - 1] - y[0]) <= \
            group_distance_m + distance_proportion * max(ranges_m[0], ranges_m[n - 1]):
        last = bounds[n_groups - 1]
        shift = n - last
        gx = np.empty(n)
        gy = np.empty(n)
        gx[:shift] = x[last:]
        gx[shift:] = x[:last]
        gy[:shift] = y[last:]
        gy[shift:] = y[:last]
        # The merged group ends where the first one ended; the others move by ``shift``.
        for g in range(1, n_groups):
            bounds[g] += shift
        n_groups -= 1
        bounds[n_groups] = n
    stack_s = np.empty(2 * n + 2, dtype=np.int64)
    stack_e = np.empty(2 * n + 2, dtype=np.int64)
    seg = np.empty(4)
    two_r = 2.0 * max_circle_radius_m
    for g in range(n_groups):
        s0 = bounds[g]
        e0 = bounds[g + 1]
        m = e0 - s0
        if m < min_group_points:
            continue
        chord = math.hypot(gx[e0 - 1] - gx[s0], gy[e0 - 1] - gy[s0])
        mx = 0.0
        my = 0.0
        for j in range(s0, e0):
            mx += gx[j]
            my += gy[j]
        mx /= m
        my /= m
        spread = 0.0
        for j in range(s0, e0):
            h = math.hypot(gx[j] - mx, gy[j] - my)
            if h > spread:
                spread = h
        extent = max(chord, 2.0 * spread)
        if extent < two_r:
            # A small object (a post, a leg, a bin): one circle, however curved.
            half = 0.5 * extent
            ax = mx - sensor_x
            ay = my - sensor_y
            norm = math.hypot(ax, ay)
            if norm == 0.0:
                norm = 1.0
            circles[n_circ, 0] = mx + ax / norm * (0.5 * half)
            circles[n_circ, 1] = my + ay / norm * (0.5 * half)
            circles[n_circ, 2] = half + radius_enlargement_m
            n_circ += 1
            continue
        # Split-and-merge; the right part is pushed first so pieces come out in scan order.
        stack_s[0] = s0
        stack_e[0] = e0
        top = 1
        while top > 0:
            top -= 1
            s = stack_s[top]
            e = stack_e[top]
            cnt = e - s
            if cnt < 2:
                continue
            if cnt >= 3:
                px = gx[s]
                py = gy[s]
                abx = gx[e - 1] - px
                aby = gy[e - 1] - py
                nab = math.hypot(abx, aby)
                k = 0
                best = -1.0
                for j in range(s, e):
                    if nab < 1e-9:
                        d = math.hypot(gx[j] - px, gy[j] - py)
                    else:
                        d = abs(abx * (gy[j] - py) - aby * (gx[j] - px)) / nab
                    if d > best:
                        best = d
                        k = j - s
                if best > split_distance_m and 0 < k < cnt - 1:
                    stack_s[top] = s + k
                    stack_e[top] = e
                    stack_s[top + 1] = s
                    stack_e[top + 1] = s + k + 1
                    top += 2
                    continue
            _fit_piece(gx, gy, s, e, seg)
            length = math.hypot(seg[2] - seg[0], seg[3] - seg[1])
            if length < two_r:
                mid_x = 0.5 * (seg[0] + seg[2])
                mid_y = 0.5 * (seg[1] + seg[3])
                ax = mid_x - sensor_x
                ay = mid_y - sensor_y
                norm = math.hypot(ax, ay)
                if norm == 0.0:
                    norm = 1.0
                push = length / (2.0 * _SQRT3)
                circles[n_circ, 0] = mid_x + ax / norm * push
                circles[n_circ, 1] = mid_y + ay / norm * push
                circles[n_circ, 2] = length / _SQRT3 + radius_enlargement_m
                n_circ += 1
            else:
                segments[n_seg, :] = seg
                n_seg += 1
    return segments[:n_seg], circles[:n_circ]
