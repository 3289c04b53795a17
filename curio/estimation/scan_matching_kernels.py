"""Compiled kernels of the correlative scan matcher (numba, ``nogil``).

* :func:`splat_points` draws a likelihood grid: every cell holds ``exp(−d² / 2σ²)`` of the
  distance ``d`` from its centre to the nearest cell holding a point (within 3σ; the maximum
  over points, so overlapping scans do not add up).
* :func:`max_pyramid` precomputes, for each depth ``h``, the maximum of the grid over the
  ``2^h × 2^h`` block of cells starting at each cell — the bounds that make branch and bound
  exact (Hess, Kohler, Rapp, Andor: *Real-time loop closure in 2D LIDAR SLAM*, ICRA 2016,
  section V-C).
* :func:`branch_and_bound` finds the rotation and cell offset that maximise the mean grid value
  under a scan's points, over a window of offsets and a fan of rotations, visiting the
  candidates best bound first and pruning every subtree whose bound cannot beat the best
  complete solution found so far.

Grids are indexed ``[row, col]``; cell ``(r, c)`` covers ``[ox + c·res, ox + (c+1)·res) ×
[oy + r·res, oy + (r+1)·res)`` in the frame the points are given in (``map`` or a submap's
frame), metres. The first call compiles the kernels (a few seconds); numba caches the machine
code on disk.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit  # type: ignore[import-untyped]

__all__ = ["branch_and_bound", "max_pyramid", "splat_points"]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def splat_points(points, ox, oy, res, sigma, out):  # type: ignore[no-untyped-def]
    """Draw ``points`` (``(M, 2)`` metres) into ``out`` (``(H, W)`` float32, in place).

    Each point is snapped to the centre of its cell (at most half a cell off, far below the
    search's resolution) and every cell within 3σ becomes ``max(cell, exp(−d² / 2σ²))``; a
    cell hit by many points is drawn once.
    """
    h, w = out.shape
    rad = math.ceil(3.0 * sigma / res)
    kern = np.empty((2 * rad + 1, 2 * rad + 1), dtype=np.float32)
    for a in range(2 * rad + 1):
        for b in range(2 * rad + 1):
            d2 = ((a - rad) ** 2 + (b - rad) ** 2) * res * res
            kern[a, b] = math.exp(-d2 / (2.0 * sigma * sigma))
    hit = np.zeros((h, w), dtype=np.bool_)
    for n in range(points.shape[0]):
        c0 = math.floor((points[n, 0] - ox) / res)
        r0 = math.floor((points[n, 1] - oy) / res)
        if 0 <= r0 < h and 0 <= c0 < w:
            hit[r0, c0] = True
    for r0 in range(h):
        for c0 in range(w):
            if not hit[r0, c0]:
                continue
            for r in range(max(0, r0 - rad), min(h, r0 + rad + 1)):
                for c in range(max(0, c0 - rad), min(w, c0 + rad + 1)):
                    v = kern[r - r0 + rad, c - c0 + rad]
                    if v > out[r, c]:
                        out[r, c] = v


@njit(cache=True, nogil=True)  # type: ignore[misc]
def max_pyramid(grid, depth):  # type: ignore[no-untyped-def]
    """``(depth + 1, H, W)`` float32: level ``h`` holds the max over ``[r, r+2^h) × [c, c+2^h)``.

    Cells past the grid's edge count as 0.
    """
    h, w = grid.shape
    pyr = np.zeros((depth + 1, h, w), dtype=np.float32)
    pyr[0] = grid
    tmp = np.zeros((h, w), dtype=np.float32)
    for lev in range(1, depth + 1):
        half = 1 << (lev - 1)
        prev = pyr[lev - 1]
        for r in range(h):
            for c in range(w):
                a = prev[r, c]
                if c + half < w:
                    b = prev[r, c + half]
                    if b > a:
                        a = b
                tmp[r, c] = a
        cur = pyr[lev]
        for r in range(h):
            for c in range(w):
                a = tmp[r, c]
                if r + half < h:
                    b = tmp[r + half, c]
                    if b > a:
                        a = b
                cur[r, c] = a
    return pyr


@njit(cache=True, nogil=True, inline="always")  # type: ignore[misc]
def _score(pyr, lev, rows, cols, k, di, dj):  # type: ignore[no-untyped-def]
    """Mean of level ``lev`` under the points of rotation ``k`` shifted by ``(di, dj)``: an upper
    bound of the score of every offset in the block ``[di, di+2^lev) × [dj, dj+2^lev)``."""
    _, h, w = pyr.shape
    size = 1 << lev
    n = rows.shape[1]
    s = 0.0
    for p in range(n):
        r = rows[k, p] + di
        c = cols[k, p] + dj
        # A block that starts before the grid but reaches into it is bounded by the block at
        # the edge (which covers the part inside); one entirely outside reads 0.
        if r < 0:
            if r + size <= 0:
                continue
            r = 0
        if c < 0:
            if c + size <= 0:
                continue
            c = 0
        if r < h and c < w:
            s += pyr[lev, r, c]
    return s / n


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _discretise(points, ox, oy, res, cx, cy, cth, n_rot, dth):  # type: ignore[no-untyped-def]
    n = points.shape[0]
    rows = np.empty((2 * n_rot + 1, n), dtype=np.int64)
    cols = np.empty((2 * n_rot + 1, n), dtype=np.int64)
    for k in range(2 * n_rot + 1):
        th = cth + (k - n_rot) * dth
        c = math.cos(th)
        s = math.sin(th)
        for p in range(n):
            x = cx + c * points[p, 0] - s * points[p, 1]
            y = cy + s * points[p, 0] + c * points[p, 1]
            cols[k, p] = math.floor((x - ox) / res)
            rows[k, p] = math.floor((y - oy) / res)
    return rows, cols


@njit(cache=True, nogil=True)  # type: ignore[misc]
def branch_and_bound(pyr, ox, oy, res, points, cx, cy, cth,  # type: ignore[no-untyped-def]
                     window_cells, n_rot, dth, min_score, ex_i=0, ex_j=0, ex_k=0,
                     ex_cells=-1, ex_rot=0):
    """Best pose of ``points`` (``(N, 2)``, sensor frame) on the grid of ``pyr``.

    Candidates: rotations ``cth + k·dth`` for ``k = −n_rot … n_rot``; translations
    ``(cx + dj·res, cy + di·res)`` for integer ``di, dj`` in ``[−window_cells, window_cells]``.
    With ``ex_cells ≥ 0`` the solutions within ``ex_cells`` cells of ``(ex_i, ex_j)`` and
    ``ex_rot`` steps of rotation ``ex_k`` (offsets as returned, over ``res`` and ``dth``) are
    excluded — the second-best peak, to tell a unique match from an ambiguous one.

    Returns:
        ``(score, dx_m, dy_m, dth_rad, visited)``: the best mean value (``−1`` if none reaches
        ``min_score``), its offset from ``(cx, cy, cth)`` and the number of scored candidates.
    """
    depth = pyr.shape[0] - 1
    rows, cols = _discretise(points, ox, oy, res, cx, cy, cth, n_rot, dth)
    step = 1 << depth
    n_side = (2 * window_cells) // step + 1
    n_top = (2 * n_rot + 1) * n_side * n_side
    cap = n_top + 64 * (depth + 1) * 4 + 16
    st_k = np.empty(cap, dtype=np.int64)
    st_i = np.empty(cap, dtype=np.int64)
    st_j = np.empty(cap, dtype=np.int64)
    st_l = np.empty(cap, dtype=np.int64)
    st_s = np.empty(cap, dtype=np.float64)
    # Top level, pushed in ascending order of score so the best is popped first.
    top_s = np.empty(n_top, dtype=np.float64)
    top_k = np.empty(n_top, dtype=np.int64)
    top_i = np.empty(n_top, dtype=np.int64)
    top_j = np.empty(n_top, dtype=np.int64)
    m = 0
    for k in range(2 * n_rot + 1):
        for a in range(n_side):
            for b in range(n_side):
                di = -window_cells + a * step
                dj = -window_cells + b * step
                top_s[m] = _score(pyr, depth, rows, cols, k, di, dj)
                top_k[m] = k
                top_i[m] = di
                top_j[m] = dj
                m += 1
    order = np.argsort(top_s)
    sp = 0
    for q in range(n_top):
        o = order[q]
        if top_s[o] >= min_score:
            st_k[sp] = top_k[o]
            st_i[sp] = top_i[o]
            st_j[sp] = top_j[o]
            st_l[sp] = depth
            st_s[sp] = top_s[o]
            sp += 1
    visited = n_top
    best = min_score
    best_k = -1
    best_i = 0
    best_j = 0
    ch_s = np.empty(4, dtype=np.float64)
    ch_i = np.empty(4, dtype=np.int64)
    ch_j = np.empty(4, dtype=np.int64)
    while sp > 0:
        sp -= 1
        k = st_k[sp]
        di = st_i[sp]
        dj = st_j[sp]
        lev = st_l[sp]
        s = st_s[sp]
        if s <= best and best_k >= 0:
            continue
        if s < best:
            continue
        if lev == 0:
            if (ex_cells >= 0 and abs(di - ex_i) <= ex_cells and abs(dj - ex_j) <= ex_cells
                    and abs(k - n_rot - ex_k) <= ex_rot):
                continue
            best = s
            best_k = k
            best_i = di
            best_j = dj
            continue
        half = 1 << (lev - 1)
        nc = 0
        for a in range(2):
            for b in range(2):
                ci = di + a * half
                cj = dj + b * half
                if ci > window_cells or cj > window_cells:
                    continue
                ch_s[nc] = _score(pyr, lev - 1, rows, cols, k, ci, cj)
                ch_i[nc] = ci
                ch_j[nc] = cj
                nc += 1
        visited += nc
        corder = np.argsort(ch_s[:nc])
        for q in range(nc):
            o = corder[q]
            if ch_s[o] >= best and sp < cap:
                st_k[sp] = k
                st_i[sp] = ch_i[o]
                st_j[sp] = ch_j[o]
                st_l[sp] = lev - 1
                st_s[sp] = ch_s[o]
                sp += 1
    if best_k < 0:
        return -1.0, 0.0, 0.0, 0.0, visited
    return best, best_j * res, best_i * res, (best_k - n_rot) * dth, visited
