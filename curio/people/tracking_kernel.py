"""Compiled steps of the people detector, tracker and node (numba kernels, cached on disk).

Each kernel does the floating-point operations of the numpy (or filterpy) code it stands for,
in the same order and without fused multiply-adds, so its results are the same to the last
bit; ``tests/unit/test_people_kernels.py`` checks each against its reference formula. They
replace dozens of numpy calls on arrays of a few to a few hundred elements, whose overhead
was most of the people node's time. What stays in numpy: ``cos``/``sin`` (numpy's own SIMD
versions, not libm's) and every product that goes through BLAS (its kernels' order and fused
multiply-adds are its own).

* :func:`beam_angles` — the returns within range: beam indices, ranges, angles in ``map``.
* :func:`end_points_off_map` — their end points (``map``, m) and those farther than a margin
  from the static map's obstacles (a map whose origin is not rotated; see
  :meth:`curio.people.detect.StaticMap.distance_at`).
* :func:`map_distances` — the static map's distance field at map points (same condition).
* :func:`scan_segments` — the detector's segments (beam order, seam of a full-circle scan).
* :func:`close_pairs` — the pairs of legs near enough along x and y to be worth measuring.
* :func:`kalman_correct` — filterpy's ``KalmanFilter.update`` for the tracker's
  position-only measurement of a constant-velocity state, up to its Joseph-form product.
* :func:`beams_near` — the beams ending near predicted people (the localiser's question).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["beam_angles", "beams_near", "close_pairs", "end_points_off_map", "kalman_correct",
           "map_distances", "pairwise_sum", "scan_segments"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def beam_angles(valid: B, ranges: F64, max_range_m: float, angle_min: float, increment: float,
                yaw: float) -> tuple[I64, F64, F64]:  # pragma: no cover - compiled
    """The beams that are ``valid`` and no longer than ``max_range_m``: their indices, ranges
    (m) and angles (rad, ``angle_min + index * increment + yaw``, as numpy sums them)."""
    n = 0
    for i in range(valid.shape[0]):
        if valid[i] and ranges[i] <= max_range_m:
            n += 1
    idx = np.empty(n, dtype=np.int64)
    r = np.empty(n)
    ang = np.empty(n)
    k = 0
    for i in range(valid.shape[0]):
        if valid[i] and ranges[i] <= max_range_m:
            idx[k] = i
            r[k] = ranges[i]
            ang[k] = (angle_min + float(i) * increment) + yaw
            k += 1
    return idx, r, ang


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _cell_distance(x: float, y: float, ox: float, oy: float, resolution: float,
                   distance: F64) -> float:  # pragma: no cover - compiled
    """``distance`` at the cell of map point (x, y): ``floor((p + o) / resolution)``, ``o =
    (ox, oy)`` the inverse origin's translation of a map whose origin is not rotated; −1
    outside the map."""
    col = math.floor((x + ox) / resolution)
    row = math.floor((y + oy) / resolution)
    if 0 <= row < distance.shape[0] and 0 <= col < distance.shape[1]:
        return float(distance[row, col])
    return -1.0


@njit(cache=True, nogil=True)  # type: ignore[misc]
def map_distances(xy: F64, ox: float, oy: float, resolution: float,
                  distance: F64) -> F64:  # pragma: no cover - compiled
    """:func:`_cell_distance` at each ``(N, 2)`` map point."""
    out = np.empty(xy.shape[0])
    for i in range(xy.shape[0]):
        out[i] = _cell_distance(xy[i, 0], xy[i, 1], ox, oy, resolution, distance)
    return out


@njit(cache=True, nogil=True)  # type: ignore[misc]
def end_points_off_map(idx: I64, x: float, y: float, r: F64, c: F64, s: F64, ox: float,
                       oy: float, resolution: float, distance: F64,
                       margin: float) -> tuple[I64, F64, F64]:  # pragma: no cover - compiled
    """The returns whose end point (``x + r c``, ``y + r s``: map, m) lies farther than
    ``margin`` (m) from the map's obstacles: their beam indices, end points ``(N, 2)`` and
    ranges. ``distance`` is the map's distance field, its cell at ``floor((p + o) /
    resolution)`` with ``o = (ox, oy)`` the inverse origin's translation (a map whose origin is
    not rotated); outside the map: −1."""
    n = r.shape[0]
    keep = np.empty(n, dtype=np.bool_)
    px = np.empty(n)
    py = np.empty(n)
    kept = 0
    for i in range(n):
        px[i] = x + r[i] * c[i]
        py[i] = y + r[i] * s[i]
        keep[i] = _cell_distance(px[i], py[i], ox, oy, resolution, distance) > margin
        if keep[i]:
            kept += 1
    out_idx = np.empty(kept, dtype=np.int64)
    pts = np.empty((kept, 2))
    out_r = np.empty(kept)
    k = 0
    for i in range(n):
        if keep[i]:
            out_idx[k] = idx[i]
            pts[k, 0] = px[i]
            pts[k, 1] = py[i]
            out_r[k] = r[i]
            k += 1
    return out_idx, pts, out_r


@njit(cache=True, nogil=True)  # type: ignore[misc]
def pairwise_sum(a: F64, start: int, n: int, col: int) -> float:  # pragma: no cover
    """``a[start:start + n, col]`` summed as numpy's add-reduction sums a strided run: below 8
    elements in order from −0.0, up to 128 in 8 interleaved partial sums, beyond that halved
    (at a multiple of 8) and each half summed so."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[start + i, col]
        return res
    if n <= 128:
        r0, r1 = a[start, col], a[start + 1, col]
        r2, r3 = a[start + 2, col], a[start + 3, col]
        r4, r5 = a[start + 4, col], a[start + 5, col]
        r6, r7 = a[start + 6, col], a[start + 7, col]
        i = 8
        while i < n - n % 8:
            j = start + i
            r0 += a[j, col]
            r1 += a[j + 1, col]
            r2 += a[j + 2, col]
            r3 += a[j + 3, col]
            r4 += a[j + 4, col]
            r5 += a[j + 5, col]
            r6 += a[j + 6, col]
            r7 += a[j + 7, col]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[start + i, col]
            i += 1
        return float(res)
    n2 = n // 2
    n2 -= n2 % 8
    return float(pairwise_sum(a, start, n2, col) + pairwise_sum(a, start + n2, n - n2, col))


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _split(idx: I64, pts: F64, r: F64, i: int, j: int, circle_beams: int,
           gap_m: float) -> bool:  # pragma: no cover - compiled
    """Whether returns ``i`` and ``j`` (the next) belong to different segments: more than
    three beams apart (modulo ``circle_beams`` when not 0) or farther apart than ``gap_m`` +
    1 % of ``j``'s range."""
    step = idx[j] - idx[i]
    if circle_beams:
        step %= circle_beams
    gap = math.hypot(pts[j, 0] - pts[i, 0], pts[j, 1] - pts[i, 1])
    return bool(gap > gap_m + 0.01 * r[j] or step > 3)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def scan_segments(idx: I64, pts: F64, r: F64, circle_beams: int, gap_m: float,
                  max_width_m: float) -> tuple[I64, F64, I64, I64, F64, F64, F64,
                                               I64]:  # pragma: no cover - compiled
    """The segments of the returns ``idx``/``pts``/``r`` (beam order; see
    :meth:`curio.people.detect.Detector._segments`).

    A full-circle scan (``circle_beams``: its beam count, else 0) is first rotated to start
    just after a split, so no segment straddles its seam. Returns the (rotated) beam indices
    and points, each segment's first and one-past-last return, its centre (the mean of its
    points, summed as ``numpy.add.reduceat`` sums), its width (first to last point, m), and
    the segments no wider than ``max_width_m`` made of two returns or more (or one, 3 m or
    farther).
    """
    n = idx.shape[0]
    shift = 0
    if circle_beams and n > 1:
        last = -1
        for i in range(n):
            if _split(idx, pts, r, i, (i + 1) % n, circle_beams, gap_m):
                last = i
        if last != -1 and last != n - 1:
            shift = last + 1
    if shift:
        order = np.empty(n, dtype=np.int64)
        for i in range(n):
            order[i] = (i + shift) % n
        idx, pts, r = idx[order], pts[order], r[order]
    splits = 0
    for i in range(n - 1):
        if _split(idx, pts, r, i, i + 1, circle_beams, gap_m):
            splits += 1
    m = splits + 1 if n else 0
    starts = np.empty(m, dtype=np.int64)
    ends = np.empty(m, dtype=np.int64)
    if n:
        starts[0] = 0
        k = 1
        for i in range(n - 1):
            if _split(idx, pts, r, i, i + 1, circle_beams, gap_m):
                ends[k - 1] = i + 1
                starts[k] = i + 1
                k += 1
        ends[m - 1] = n
    cx = np.empty(m)
    cy = np.empty(m)
    width = np.empty(m)
    kept = 0
    keep = np.empty(m, dtype=np.bool_)
    for k in range(m):
        s, e = starts[k], ends[k]
        count = e - s
        cx[k] = (pts[s, 0] + pairwise_sum(pts, s + 1, count - 1, 0)) / count
        cy[k] = (pts[s, 1] + pairwise_sum(pts, s + 1, count - 1, 1)) / count
        width[k] = math.hypot(pts[e - 1, 0] - pts[s, 0], pts[e - 1, 1] - pts[s, 1])
        keep[k] = width[k] <= max_width_m and (count >= 2 or r[s] >= 3.0)
        if keep[k]:
            kept += 1
    which = np.empty(kept, dtype=np.int64)
    j = 0
    for k in range(m):
        if keep[k]:
            which[j] = k
            j += 1
    return idx, pts, starts, ends, cx, cy, width, which


@njit(cache=True, nogil=True)  # type: ignore[misc]
def close_pairs(xy: F64, bound: float) -> tuple[I64, I64]:  # pragma: no cover - compiled
    """The pairs ``i < j`` of the points ``xy`` ``(N, 2)`` no farther apart than ``bound``
    along x and along y (every pair when a coordinate is NaN), in row-major order."""
    n = xy.shape[0]
    every = False
    for i in range(n):
        every = every or math.isnan(xy[i, 0]) or math.isnan(xy[i, 1])
    first = np.empty(n * (n - 1) // 2, dtype=np.int64)
    second = np.empty(n * (n - 1) // 2, dtype=np.int64)
    k = 0
    for i in range(n):
        for j in range(i + 1, n):
            if every or (abs(xy[i, 0] - xy[j, 0]) <= bound
                         and abs(xy[i, 1] - xy[j, 1]) <= bound):
                first[k] = i
                second[k] = j
                k += 1
    return first[:k], second[:k]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def kalman_correct(x: F64, p: F64, h: F64, r: F64, zx: float,
                   zy: float) -> tuple[bool, F64, F64, F64]:  # pragma: no cover - compiled
    """filterpy's ``KalmanFilter.update`` of state ``x`` ``(4, 1)`` and covariance ``p``
    ``(4, 4)`` with the measurement ``(zx, zy)`` of ``h = [I₂ 0]``, covariance ``r``, up to its
    last product: returns ``(ok, x', I − KH, K R Kᵀ)``; then ``P' = (I − KH) P (I − KH)ᵀ +
    K R Kᵀ`` (BLAS products: the caller's). ``ok`` is False, and nothing else meaningful,
    unless everything is finite, ``r`` diagonal and ``p`` without covariance between the x
    (0, 2) and y (1, 3) components — what the tracker's filters always have.

    With that structure each of filterpy's products has at most one non-zero term per
    element (``h`` selects, ``S = H P Hᵀ + R`` is diagonal, LAPACK's inverse of a diagonal
    2 × 2 matrix is the reciprocals, ``K = P Hᵀ S⁻¹`` scales columns): whatever order or
    fused multiply-adds BLAS uses, each is that one term, rounded once, as here.
    """
    x_new = np.empty((4, 1))
    i_kh = np.eye(4)
    krk = np.empty((4, 4))
    ok = (r[0, 1] == 0.0 and r[1, 0] == 0.0 and math.isfinite(r[0, 0])
          and math.isfinite(r[1, 1]) and math.isfinite(zx) and math.isfinite(zy))
    for i in range(4):
        ok = ok and math.isfinite(x[i, 0])
        ok = ok and h[0, i] == (1.0 if i == 0 else 0.0) and h[1, i] == (1.0 if i == 1 else 0.0)
        for j in range(4):
            ok = ok and math.isfinite(p[i, j]) and (i % 2 == j % 2 or p[i, j] == 0.0)
    s0 = p[0, 0] + r[0, 0]
    s1 = p[1, 1] + r[1, 1]
    if not ok or s0 == 0.0 or s1 == 0.0:
        return False, x_new, i_kh, krk
    si0 = 1.0 / s0
    si1 = 1.0 / s1
    y0 = zx - x[0, 0]
    y1 = zy - x[1, 0]
    k = np.empty((4, 2))
    for i in range(4):
        k[i, 0] = p[i, 0] * si0
        k[i, 1] = p[i, 1] * si1
        x_new[i, 0] = x[i, 0] + (k[i, 0] * y0 + k[i, 1] * y1)
        i_kh[i, 0] -= k[i, 0]
        i_kh[i, 1] -= k[i, 1]
    for i in range(4):
        kr0 = k[i, 0] * r[0, 0]
        kr1 = k[i, 1] * r[1, 1]
        for j in range(4):
            krk[i, j] = kr0 * k[j, 0] + kr1 * k[j, 1]
    return True, x_new, i_kh, krk


@njit(cache=True, nogil=True)  # type: ignore[misc]
def beams_near(valid: B, ranges: F64, c: F64, s: F64, x: float, y: float, people: F64,
               reach_sq: float) -> tuple[B, bool]:  # pragma: no cover - compiled
    """The ``valid`` beams whose end point (``x + r c``, ``y + r s``: map, m) lies within
    ``√reach_sq`` of one of ``people`` ``(P, 2)`` (``(ex − px)² + (ey − py)² <= reach_sq``),
    and whether there is any."""
    n = ranges.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    found = False
    for i in range(n):
        if not valid[i]:
            continue
        ex = x + ranges[i] * c[i]
        ey = y + ranges[i] * s[i]
        for j in range(people.shape[0]):
            dx = ex - people[j, 0]
            dy = ey - people[j, 1]
            if dx * dx + dy * dy <= reach_sq:
                out[i] = True
                found = True
                break
    return out, found
