"""Compiled inner loop of the mapper's log-odds grid (numba, ``nogil``): one scan's rays.

Cell ``(r, c)`` of the grid covers ``[ox + c·res, ox + (c+1)·res) × [oy + r·res, oy +
(r+1)·res)`` in ``map`` (metres). The first call compiles the kernel (a few seconds); numba
caches the machine code on disk.
"""

from __future__ import annotations

import math

from numba import njit  # type: ignore[import-untyped]

__all__ = ["integrate_rays"]

STEP_CELLS = 0.8  # free-space samples every 0.8 cell along a ray


@njit(cache=True, nogil=True)  # type: ignore[misc]
def integrate_rays(logodds, seen, mark, scan_id, ox, oy, res,  # type: ignore[no-untyped-def]
                   x0, y0, ends, n_hit, l_free, l_occ, l_max):
    """Add one scan to the grid (in place).

    Args:
        logodds: ``(H, W)`` float32 log odds.
        seen: ``(H, W)`` bool, cells ever observed.
        mark: ``(H, W)`` int64 scratch: ``2·scan_id`` marks a cell freed by this scan,
            ``2·scan_id + 1`` a cell hit by it (each cell is updated once per scan).
        scan_id: a number not used by any earlier call on this ``mark`` (≥ 1).
        ox, oy, res: the grid's corner and cell size, metres.
        x0, y0: the laser's position (the origin of every ray), metres.
        ends: ``(N, 2)`` ray ends; the first ``n_hit`` are returns (their cell is marked
            occupied and the ray stops one cell short of it), the rest clear all the way.
        l_free, l_occ: log-odds increments of a freed and of a hit cell; ``l_max`` the bound.
    """
    h, w = logodds.shape
    occ_id = 2 * scan_id + 1
    free_id = 2 * scan_id
    for n in range(n_hit):
        c = math.floor((ends[n, 0] - ox) / res)
        r = math.floor((ends[n, 1] - oy) / res)
        if 0 <= r < h and 0 <= c < w:
            mark[r, c] = occ_id
    for n in range(ends.shape[0]):
        dx = ends[n, 0] - x0
        dy = ends[n, 1] - y0
        length = math.sqrt(dx * dx + dy * dy)
        stop = length - res if n < n_hit else length
        if length <= 1e-9 or stop <= 0.0:
            continue
        step = STEP_CELLS * res
        ux = dx / length
        uy = dy / length
        k = 0
        while k * step < stop:
            d = k * step
            c = math.floor((x0 + ux * d - ox) / res)
            r = math.floor((y0 + uy * d - oy) / res)
            k += 1
            if r < 0 or r >= h or c < 0 or c >= w:
                continue
            m = mark[r, c]
            if m >= free_id:  # freed or hit by this scan already
                continue
            mark[r, c] = free_id
            v = logodds[r, c] + l_free
            logodds[r, c] = max(-l_max, min(l_max, v))
            seen[r, c] = True
    for n in range(n_hit):
        c = math.floor((ends[n, 0] - ox) / res)
        r = math.floor((ends[n, 1] - oy) / res)
        if 0 <= r < h and 0 <= c < w and mark[r, c] == occ_id:
            mark[r, c] = free_id  # counted once
            v = logodds[r, c] + l_occ
            logodds[r, c] = max(-l_max, min(l_max, v))
            seen[r, c] = True
