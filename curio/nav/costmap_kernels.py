"""Compiled inner loop of the costmap's obstacle layer (numba, ``nogil``): one scan's
ray-trace clearing and marking.

Everything works in continuous grid coordinates of the master grid: ``(col, row)`` in cells,
cell ``(r, c)`` covering ``[c, c+1) × [r, r+1)``. The first call compiles the kernel (about a
second); numba caches the machine code on disk.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit  # type: ignore[import-untyped]

__all__ = ["trace_scan"]

STEP_CELLS = 0.5  # clearing samples every half cell along a ray


@njit(cache=True, nogil=True)  # type: ignore[misc]
def trace_scan(obstacles, seen, static_lethal, near_static, unknown,  # type: ignore[no-untyped-def]
               master, ox, oy, dirs, clear_len_cells, mark_len_cells, touched, out):
    """Clear, then mark, the obstacle layer for one scan; report what changed.

    Args:
        obstacles: ``(H, W)`` bool obstacle layer (updated in place).
        seen: ``(H, W)`` bool, cells ever observed (updated in place).
        static_lethal: ``(H, W)`` bool, lethal cells of the static map.
        near_static: ``(H, W)`` bool, free cells next to a mapped wall: a return there is
            taken as the wall (lidar noise) and marks nothing.
        unknown: ``(H, W)`` bool, unknown cells of the static map.
        master: ``(H, W)`` uint8 current master costs (read only).
        ox, oy: the ray origin (the lidar), continuous grid coordinates (cells).
        dirs: ``(N, 2)`` unit ray directions in the grid frame.
        clear_len_cells: ``(N,)`` clearing length per ray, cells; a ray clears the samples
            ``k · STEP_CELLS`` short of ``length − 0.5`` (the end cell is the return's); rays
            of length ≤ 0.5 clear nothing.
        mark_len_cells: ``(N,)`` distance to the return to mark, cells; negative: no mark.
        touched: ``(H, W)`` uint8 scratch, all zero (left all zero).
        out: ``(8,)`` int64, filled with the bounding boxes ``[r0, r1, c0, c1]`` (end
            exclusive; ``r0 > r1`` when empty) of the cells whose *effective* lethal state
            (static or obstacle) changed, then of unknown, not-yet-costed cells that a ray
            revealed.

    Returns:
        The number of changed cells.
    """
    h, w = obstacles.shape
    n = dirs.shape[0]
    cap = 0
    for i in range(n):
        if clear_len_cells[i] > 0.5:
            cap += math.ceil(clear_len_cells[i] / STEP_CELLS)
        cap += 1
    cells = np.empty(cap, dtype=np.int64)
    old = np.empty(cap, dtype=np.bool_)
    count = 0
    big = h + w + 1
    vr0, vr1, vc0, vc1 = big, -1, big, -1  # revealed unknown cells
    # Clearing.
    for i in range(n):
        lc = clear_len_cells[i]
        if lc <= 0.5:
            continue
        dx, dy = dirs[i, 0], dirs[i, 1]
        k_max = math.ceil(lc / STEP_CELLS)
        for k in range(k_max):
            t = k * STEP_CELLS
            if not t < lc - 0.5:
                break
            c = math.floor(ox + dx * t)
            r = math.floor(oy + dy * t)
            if r < 0 or r >= h or c < 0 or c >= w:
                continue
            if touched[r, c] == 0:
                touched[r, c] = 1
                cells[count] = r * w + c
                old[count] = obstacles[r, c]
                count += 1
                if unknown[r, c] and master[r, c] == 255:
                    vr0, vr1 = min(vr0, r), max(vr1, r + 1)
                    vc0, vc1 = min(vc0, c), max(vc1, c + 1)
            obstacles[r, c] = False
            seen[r, c] = True
    # Marking (a return wins over a clearing ray of the same scan).
    for i in range(n):
        m = mark_len_cells[i]
        if m < 0.0:
            continue
        c = math.floor(ox + dirs[i, 0] * m)
        r = math.floor(oy + dirs[i, 1] * m)
        if r < 0 or r >= h or c < 0 or c >= w:
            continue
        seen[r, c] = True
        if near_static[r, c]:
            continue
        if touched[r, c] == 0:
            touched[r, c] = 1
            cells[count] = r * w + c
            old[count] = obstacles[r, c]
            count += 1
        obstacles[r, c] = True
    # What changed for the costs: the obstacle layer, outside the static walls.
    cr0, cr1, cc0, cc1 = big, -1, big, -1
    changed = 0
    for j in range(count):
        r = cells[j] // w
        c = cells[j] - r * w
        touched[r, c] = 0
        if obstacles[r, c] != old[j] and not static_lethal[r, c]:
            changed += 1
            cr0, cr1 = min(cr0, r), max(cr1, r + 1)
            cc0, cc1 = min(cc0, c), max(cc1, c + 1)
    out[0], out[1], out[2], out[3] = cr0, cr1, cc0, cc1
    out[4], out[5], out[6], out[7] = vr0, vr1, vc0, vc1
    return changed
