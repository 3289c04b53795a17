"""Compiled inner loop of the local controller's collision check (numba, ``nogil``): the
highest cost under the footprint's outline at each pose of a batch of trajectories.

The arithmetic is the numpy expression it replaces, element by element in the same order
(no fastmath), so the result is the same bit for bit; the sines and cosines of the headings
stay in numpy and come in as arguments. The first call compiles the kernel (about a second);
numba caches the machine code on disk.
"""

from __future__ import annotations

import math

from numba import njit  # type: ignore[import-untyped]

__all__ = ["outline_costs"]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def outline_costs(grid, trajs, c, s, per, ox, oy, rotated,  # type: ignore[no-untyped-def]
                  oc, os_, res, lethal, out):
    """Fill ``out`` ``(M, K)`` with the max cost of ``grid`` under the outline at each pose.

    Args:
        grid: ``(H, W)`` uint8 costs.
        trajs: ``(M, K, 3)`` poses (x, y, yaw) in the grid's parent frame.
        c, s: ``(M, K, 1)`` cosine and sine of the headings.
        per: ``(P, 2)`` outline points in ``base_link``.
        ox, oy: the grid origin; ``rotated``: whether its yaw is non-zero, with ``oc``, ``os_``
            its cosine and sine.
        res: cell size, metres.
        lethal: the cost of an off-grid point.
        out: ``(M, K)`` uint8, overwritten.
    """
    h, w = grid.shape
    m, k = trajs.shape[0], trajs.shape[1]
    n = per.shape[0]
    fh, fw = float(h), float(w)
    nos = -os_
    for i in range(m):
        for j in range(k):
            x = trajs[i, j, 0]
            y = trajs[i, j, 1]
            cc = c[i, j, 0]
            ss = s[i, j, 0]
            best = 0
            for p in range(n):
                p0 = per[p, 0]
                p1 = per[p, 1]
                px = x + cc * p0 - ss * p1
                py = y + ss * p0 + cc * p1
                if rotated:
                    gx = oc * (px - ox) + os_ * (py - oy)
                    gy = nos * (px - ox) + oc * (py - oy)
                else:
                    gx = px - ox
                    gy = py - oy
                fc = math.floor(gx / res)
                fr = math.floor(gy / res)
                # Compared as floats: also false for nan and ±inf, which numpy's cast to int64
                # sends to the lowest integer, off the grid as well.
                if fr >= 0.0 and fr < fh and fc >= 0.0 and fc < fw:
                    v = grid[int(fr), int(fc)]
                else:
                    v = lethal
                if v > best:
                    best = v
            out[i, j] = best
