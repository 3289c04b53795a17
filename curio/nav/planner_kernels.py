"""Compiled inner loops of the global planner (numba, ``nogil``): grid A* and path shortcutting.

Everything here works in grid index space: cell ``(row, col)`` with its centre at integer
coordinates, flattened as ``row * width + col``. Per-cell traversal costs come from a 256-entry
lookup table ``lut`` indexed by the costmap value (``lut[v] < 0`` means not traversable); a step
from cell ``a`` to a neighbour ``b`` costs ``step_length_cells * (lut[a] + lut[b]) / 2`` (the
same definition as scikit-image's ``MCP_Geometric``), with ``step_length`` 1 or √2.

The kernels hold no state and release the GIL, so several plans may run in threads at once.
The first call compiles them (a few seconds); the result is cached on disk by numba.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit  # type: ignore[import-untyped]

from curio.nav.costs import INSCRIBED, MAX_NON_OBSTACLE

__all__ = ["astar", "line_cost", "segments_clear", "shortcut", "trace_path"]

_SQRT2 = math.sqrt(2.0)
_DR = np.array([-1, -1, -1, 0, 0, 1, 1, 1], dtype=np.int64)
_DC = np.array([-1, 0, 1, -1, 1, -1, 0, 1], dtype=np.int64)
_FIX = 1024.0  # fixed-point scale of the priorities in the open list


@njit(cache=True, nogil=True, inline="always")  # type: ignore[misc]
def _passable(flat, lut, v, w, escape_r2, start_r, start_c):  # type: ignore[no-untyped-def]
    raw = flat[v]
    if lut[raw] >= 0.0:
        return True
    if raw == INSCRIBED and escape_r2 > 0:
        vr = v // w
        vc = v - vr * w
        return (vr - start_r) ** 2 + (vc - start_c) ** 2 <= escape_r2
    return False


@njit(cache=True, nogil=True)  # type: ignore[misc]
def astar(costs, lut, start_r, start_c, goal_r, goal_c, weight,  # type: ignore[no-untyped-def]
          escape_r2, g, parent):
    """Weighted A* on an 8-connected grid with the octile heuristic.

    Args:
        costs: ``(H, W)`` uint8 costmap.
        lut: ``(256,)`` float64 traversal cost per costmap value (< 0 blocked, else >= 1).
        start_r, start_c, goal_r, goal_c: cells.
        weight: heuristic weight (>= 1; the path costs at most ``weight`` × the optimum).
        escape_r2: squared radius (cells) around the start inside which inscribed cells (253)
            are traversable at the cost of 252, so a rover whose centre is too close to an
            obstacle can drive out; 0 disables.
        g: ``(H*W,)`` float64 scratch, zero-filled (cost-to-come; valid where ``parent > 0``).
        parent: ``(H*W,)`` uint8 scratch, zero-filled; 0 unseen, 1..8 the direction index + 1
            of the step that reached the cell, 9 the start, +16 once the cell is closed.

    Diagonal steps are not allowed past the corner of a non-traversable cell.

    Returns:
        ``(found, expansions)``.
    """
    h, w = costs.shape
    flat = costs.ravel()
    sqrt2m2 = _SQRT2 - 2.0
    wt = weight * (1.0 + 1e-4)  # slight tie-break towards the goal
    start = start_r * w + start_c
    goal = goal_r * w + goal_c
    # Open list: a 4-ary min-heap of packed int64 entries, f in fixed point (1/1024 of a cost
    # unit) in the high 32 bits and the cell in the low 32 bits (one compare, one array).
    cap = 1 << 14
    heap = np.empty(cap, dtype=np.int64)
    g[start] = 0.0
    parent[start] = 9
    dx0 = abs(start_c - goal_c)
    dy0 = abs(start_r - goal_r)
    f0 = wt * (dx0 + dy0 + sqrt2m2 * min(dx0, dy0))
    heap[0] = (np.int64(f0 * _FIX) << 32) | start
    size = 1
    expansions = 0
    lut252 = lut[MAX_NON_OBSTACLE]
    low = np.int64(0xFFFFFFFF)
    offs = np.empty(8, dtype=np.int64)
    for k in range(8):
        offs[k] = _DR[k] * w + _DC[k]
    while size > 0:
        # ---- pop
        u = heap[0] & low
        size -= 1
        if size > 0:
            x = heap[size]
            i = 0
            while True:
                c = 4 * i + 1
                if c >= size:
                    break
                m = c
                best = heap[c]
                end = min(c + 4, size)
                for j in range(c + 1, end):
                    if heap[j] < best:
                        best = heap[j]
                        m = j
                if best >= x:
                    break
                heap[i] = best
                i = m
            heap[i] = x
        if parent[u] >= 16:
            continue
        if u == goal:
            return True, expansions
        parent[u] += 16
        expansions += 1
        ur = u // w
        uc = u - ur * w
        cu = lut[flat[u]]
        if cu < 0.0:  # the start inside the inscribed zone
            cu = lut252
        gu = g[u]
        interior = ur > 0 and ur < h - 1 and uc > 0 and uc < w - 1
        for k in range(8):
            vr = ur + _DR[k]
            vc = uc + _DC[k]
            if not interior and (vr < 0 or vr >= h or vc < 0 or vc >= w):
                continue
            v = u + offs[k]
            pv = parent[v]
            if pv >= 16:
                continue
            cv_raw = flat[v]
            cv = lut[cv_raw]
            if cv < 0.0:
                if cv_raw == INSCRIBED and escape_r2 > 0:
                    er = vr - start_r
                    ec = vc - start_c
                    if er * er + ec * ec <= escape_r2:
                        cv = lut252
                    else:
                        continue
                else:
                    continue
            step = 1.0
            if k == 0 or k == 2 or k == 5 or k == 7:
                # a diagonal step may not cut the corner of a blocked cell
                if not _passable(flat, lut, u + _DR[k] * w, w, escape_r2, start_r, start_c):
                    continue
                if not _passable(flat, lut, u + _DC[k], w, escape_r2, start_r, start_c):
                    continue
                step = _SQRT2
            ng = gu + step * 0.5 * (cu + cv)
            if pv == 0 or ng < g[v]:
                g[v] = ng
                parent[v] = k + 1
                dx = abs(vc - goal_c)
                dy = abs(vr - goal_r)
                f = ng + wt * (dx + dy + sqrt2m2 * min(dx, dy))
                # ---- push
                if size >= cap:
                    cap *= 2
                    nh = np.empty(cap, dtype=np.int64)
                    nh[:size] = heap[:size]
                    heap = nh
                x = (np.int64(f * _FIX) << 32) | v
                i = size
                size += 1
                while i > 0:
                    par = (i - 1) >> 2
                    if heap[par] <= x:
                        break
                    heap[i] = heap[par]
                    i = par
                heap[i] = x
    return False, expansions


@njit(cache=True, nogil=True)  # type: ignore[misc]
def trace_path(parent, w, goal_r, goal_c):  # type: ignore[no-untyped-def]
    """Follow ``parent`` from the goal back to the start; returns ``(rows, cols)`` start→goal."""
    n = 0
    r = goal_r
    c = goal_c
    while True:
        n += 1
        p = parent[r * w + c] & 15
        if p == 9 or p == 0:
            break
        r -= _DR[p - 1]
        c -= _DC[p - 1]
    rows = np.empty(n, dtype=np.int64)
    cols = np.empty(n, dtype=np.int64)
    r = goal_r
    c = goal_c
    for i in range(n - 1, -1, -1):
        rows[i] = r
        cols[i] = c
        p = parent[r * w + c] & 15
        if p == 9 or p == 0:
            break
        r -= _DR[p - 1]
        c -= _DC[p - 1]
    return rows, cols


@njit(cache=True, nogil=True)  # type: ignore[misc]
def line_cost(costs, lut, r0, c0, r1, c1, escape_r2, sr, sc):  # type: ignore[no-untyped-def]
    """Traversal cost of the straight segment between two grid points (−1 if blocked).

    Points are in index space (cell ``k`` spans ``[k − 0.5, k + 0.5)``; cell centres are
    integers). Walks every cell the segment passes through (Amanatides–Woo) and adds the length
    inside it (in cells) × ``lut[cost]``: the exact line integral of the cost field. Where the
    segment passes exactly through a cell corner, the two cells beside the corner must be
    traversable too (the same no-corner-cutting rule as :func:`astar`). Inscribed cells within
    ``escape_r2`` of ``(sr, sc)`` count as 252, as in :func:`astar`.
    """
    h, w = costs.shape
    dr = r1 - r0
    dc = c1 - c0
    length = math.sqrt(dr * dr + dc * dc)
    r = math.floor(r0 + 0.5)
    c = math.floor(c0 + 0.5)
    lut252 = lut[MAX_NON_OBSTACLE]
    if length == 0.0:
        if r < 0 or r >= h or c < 0 or c >= w:
            return -1.0
        if _passable(costs.ravel(), lut, r * w + c, w, escape_r2, sr, sc):
            return 0.0
        return -1.0
    step_r = 1 if dr > 0 else -1
    step_c = 1 if dc > 0 else -1
    inf = math.inf
    if dr != 0.0:
        tdelta_r = 1.0 / abs(dr)
        tmax_r = ((r + 0.5 * step_r) - r0) / dr
    else:
        tdelta_r = inf
        tmax_r = inf
    if dc != 0.0:
        tdelta_c = 1.0 / abs(dc)
        tmax_c = ((c + 0.5 * step_c) - c0) / dc
    else:
        tdelta_c = inf
        tmax_c = inf
    t = 0.0
    total = 0.0
    while True:
        if r < 0 or r >= h or c < 0 or c >= w:
            return -1.0
        raw = costs[r, c]
        cv = lut[raw]
        if cv < 0.0:
            if raw == INSCRIBED and escape_r2 > 0 and (r - sr) ** 2 + (c - sc) ** 2 <= escape_r2:
                cv = lut252
            else:
                return -1.0
        t_next = min(tmax_r, tmax_c, 1.0)
        total += (t_next - t) * length * cv
        if t_next >= 1.0:
            break
        if abs(tmax_r - tmax_c) <= 1e-9:
            # through a corner: the cells on both sides of it must be traversable
            for rr, cc in ((r + step_r, c), (r, c + step_c)):
                if rr < 0 or rr >= h or cc < 0 or cc >= w:
                    return -1.0
                if not _passable(costs.ravel(), lut, rr * w + cc, w, escape_r2, sr, sc):
                    return -1.0
            r += step_r
            c += step_c
            t = tmax_r
            tmax_r += tdelta_r
            tmax_c += tdelta_c
        elif tmax_r < tmax_c:
            r += step_r
            t = tmax_r
            tmax_r += tdelta_r
        else:
            c += step_c
            t = tmax_c
            tmax_c += tdelta_c
    return total


@njit(cache=True, nogil=True)  # type: ignore[misc]
def segments_clear(costs, lut, pts_rc, escape_r2, sr, sc):  # type: ignore[no-untyped-def]
    """For a polyline of ``(N, 2)`` float grid points, whether each of its N − 1 segments is
    traversable (see :func:`line_cost`)."""
    n = pts_rc.shape[0]
    out = np.empty(max(0, n - 1), dtype=np.bool_)
    for i in range(n - 1):
        out[i] = line_cost(costs, lut, pts_rc[i, 0], pts_rc[i, 1], pts_rc[i + 1, 0],
                           pts_rc[i + 1, 1], escape_r2, sr, sc) >= 0.0
    return out


@njit(cache=True, nogil=True)  # type: ignore[misc]
def shortcut(costs, lut, rows, cols, g, w, escape_r2, max_fail,  # type: ignore[no-untyped-def]
             max_span):
    """Cost-aware line-of-sight shortcutting of a grid path.

    From each anchor, the farthest later path cell is kept whose straight segment is free and
    costs no more than the path between them (``g`` differences), so the result is never more
    expensive than the A* path (it keeps the same clearance trade-off) and never crosses a
    blocked cell. Scanning ahead stops after ``max_fail`` consecutive rejections or
    ``max_span`` path cells.

    Returns the indices (into ``rows``/``cols``) of the kept vertices, first and last included.
    """
    n = rows.shape[0]
    keep = np.empty(n, dtype=np.int64)
    nk = 0
    a = 0
    keep[nk] = 0
    nk += 1
    sr = rows[0]
    sc = cols[0]
    while a < n - 1:
        best = a + 1
        fails = 0
        ga = g[rows[a] * w + cols[a]]
        j = a + 2
        end = min(n, a + max_span + 1)
        while j < end:
            gj = g[rows[j] * w + cols[j]]
            lc = line_cost(costs, lut, float(rows[a]), float(cols[a]), float(rows[j]),
                           float(cols[j]), escape_r2, sr, sc)
            if lc >= 0.0 and lc <= (gj - ga) * (1.0 + 1e-9) + 1e-9:
                best = j
                fails = 0
            else:
                fails += 1
                if fails > max_fail:
                    break
            j += 1
        keep[nk] = best
        nk += 1
        a = best
    return keep[:nk]
