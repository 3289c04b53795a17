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

__all__ = ["astar", "line_cost", "shortcut", "trace_path"]

_SQRT2 = math.sqrt(2.0)
_DR = np.array([-1, -1, -1, 0, 0, 1, 1, 1], dtype=np.int64)
_DC = np.array([-1, 0, 1, -1, 1, -1, 0, 1], dtype=np.int64)
_DL = np.array([_SQRT2, 1.0, _SQRT2, 1.0, 1.0, _SQRT2, 1.0, _SQRT2], dtype=np.float64)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _heap_push(keys, vals, size, key, val):  # type: ignore[no-untyped-def]
    if size >= keys.shape[0]:
        nk = np.empty(keys.shape[0] * 2, dtype=keys.dtype)
        nv = np.empty(vals.shape[0] * 2, dtype=vals.dtype)
        nk[:size] = keys[:size]
        nv[:size] = vals[:size]
        keys = nk
        vals = nv
    i = size
    size += 1
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= key:
            break
        keys[i] = keys[parent]
        vals[i] = vals[parent]
        i = parent
    keys[i] = key
    vals[i] = val
    return keys, vals, size


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _heap_pop(keys, vals, size):  # type: ignore[no-untyped-def]
    top = vals[0]
    size -= 1
    if size > 0:
        key = keys[size]
        val = vals[size]
        i = 0
        while True:
            child = 2 * i + 1
            if child >= size:
                break
            if child + 1 < size and keys[child + 1] < keys[child]:
                child += 1
            if keys[child] >= key:
                break
            keys[i] = keys[child]
            vals[i] = vals[child]
            i = child
        keys[i] = key
        vals[i] = val
    return top, size


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
            of the step that reached the cell, 9 the start.

    Returns:
        ``(found, expansions)``.
    """
    h, w = costs.shape
    n = h * w
    closed = np.zeros(n, dtype=np.uint8)
    dr = _DR
    dc = _DC
    dl = _DL
    sqrt2m2 = _SQRT2 - 2.0
    wt = weight * (1.0 + 1e-4)  # slight tie-break towards the goal
    start = start_r * w + start_c
    goal = goal_r * w + goal_c
    keys = np.empty(1 << 14, dtype=np.float64)
    vals = np.empty(1 << 14, dtype=np.int64)
    size = 0
    g[start] = 0.0
    parent[start] = 9
    dx0 = abs(start_c - goal_c)
    dy0 = abs(start_r - goal_r)
    h0 = dx0 + dy0 + sqrt2m2 * min(dx0, dy0)
    keys, vals, size = _heap_push(keys, vals, size, wt * h0, start)
    expansions = 0
    lut252 = lut[252]
    while size > 0:
        u, size = _heap_pop(keys, vals, size)
        if closed[u]:
            continue
        if u == goal:
            return True, expansions
        closed[u] = 1
        expansions += 1
        ur = u // w
        uc = u - ur * w
        cu = lut[costs[ur, uc]]
        if cu < 0.0:  # the start inside the inscribed zone
            cu = lut252
        gu = g[u]
        for k in range(8):
            vr = ur + dr[k]
            vc = uc + dc[k]
            if vr < 0 or vr >= h or vc < 0 or vc >= w:
                continue
            v = vr * w + vc
            if closed[v]:
                continue
            cv_raw = costs[vr, vc]
            cv = lut[cv_raw]
            if cv < 0.0:
                if cv_raw == 253 and escape_r2 > 0:
                    er = vr - start_r
                    ec = vc - start_c
                    if er * er + ec * ec <= escape_r2:
                        cv = lut252
                    else:
                        continue
                else:
                    continue
            ng = gu + dl[k] * 0.5 * (cu + cv)
            if parent[v] == 0 or ng < g[v]:
                g[v] = ng
                parent[v] = k + 1
                dx = abs(vc - goal_c)
                dy = abs(vr - goal_r)
                hv = dx + dy + sqrt2m2 * min(dx, dy)
                keys, vals, size = _heap_push(keys, vals, size, ng + wt * hv, v)
    return False, expansions


@njit(cache=True, nogil=True)  # type: ignore[misc]
def trace_path(parent, w, goal_r, goal_c):  # type: ignore[no-untyped-def]
    """Follow ``parent`` from the goal back to the start; returns ``(rows, cols)`` start→goal."""
    n = 0
    r = goal_r
    c = goal_c
    while True:
        n += 1
        p = parent[r * w + c]
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
        p = parent[r * w + c]
        if p == 9 or p == 0:
            break
        r -= _DR[p - 1]
        c -= _DC[p - 1]
    return rows, cols


@njit(cache=True, nogil=True)  # type: ignore[misc]
def line_cost(costs, lut, r0, c0, r1, c1, escape_r2, sr, sc):  # type: ignore[no-untyped-def]
    """Traversal cost of the straight segment between two cell centres (−1 if blocked).

    Samples every 0.25 cell; each sample's cell contributes ``lut[cost] × 0.25`` (cells).
    Inscribed cells within ``escape_r2`` of ``(sr, sc)`` count as 252, as in :func:`astar`.
    """
    dr = r1 - r0
    dc = c1 - c0
    length = math.sqrt(dr * dr + dc * dc)
    if length == 0.0:
        return 0.0
    n = math.ceil(length / 0.25)
    step = length / n
    total = 0.0
    h, w = costs.shape
    for i in range(n + 1):
        t = i / n
        fr = r0 + t * dr
        fc = c0 + t * dc
        r = math.floor(fr + 0.5)
        c = math.floor(fc + 0.5)
        if r < 0 or r >= h or c < 0 or c >= w:
            return -1.0
        raw = costs[r, c]
        cv = lut[raw]
        if cv < 0.0:
            if raw == 253 and escape_r2 > 0 and (r - sr) ** 2 + (c - sc) ** 2 <= escape_r2:
                cv = lut[252]
            else:
                return -1.0
        wgt = 0.5 if (i == 0 or i == n) else 1.0
        total += cv * step * wgt
    return total


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
            lc = line_cost(costs, lut, rows[a], cols[a], rows[j], cols[j], escape_r2, sr, sc)
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
