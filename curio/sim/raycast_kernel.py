"""Compiled lidar kernel (numba, ``nogil``): exact grid traversal accelerated by a distance field.

For each beam, in cell units of a grid padded with a one-cell "outside" ring:

* while the current cell's clearance (a lower bound, in cells, of the distance from any point
  of the cell to any blocked cell) is at least one cell, jump ahead by it (sphere tracing);
* otherwise take one exact Amanatides–Woo DDA step to the next cell boundary.

A beam ends at the entry face of the first occupied cell (code 1: exact range), on the outside
ring (code 2: ``inf``) or beyond ``max_t_cells`` (``inf``). The first call compiles it (about a
second); numba caches the machine code on disk.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["cast_beams"]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def cast_beams(codes: npt.NDArray[np.int8], clearance: npt.NDArray[np.float64], wp: int,
               x0: float, y0: float, dx: npt.NDArray[np.float64],
               dy: npt.NDArray[np.float64], max_t_cells: float,
               out: npt.NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """Write each beam's range in cells (``inf`` for no hit) into ``out``."""
    n = dx.shape[0]
    for i in range(n):
        ddx = dx[i]
        ddy = dy[i]
        t = 0.0
        result = math.inf
        fresh = True
        cx = 0
        cy = 0
        sx = 0
        sy = 0
        tmx = math.inf
        tmy = math.inf
        tdx = math.inf
        tdy = math.inf
        while t <= max_t_cells:
            if fresh:
                px = x0 + t * ddx
                py = y0 + t * ddy
                cx = int(px)
                cy = int(py)
                if ddx > 0.0:
                    sx = 1
                    tdx = 1.0 / ddx
                    tmx = t + (cx + 1.0 - px) * tdx
                elif ddx < 0.0:
                    sx = -1
                    tdx = -1.0 / ddx
                    tmx = t + (px - cx) * tdx
                else:
                    sx = 0
                    tmx = math.inf
                if ddy > 0.0:
                    sy = 1
                    tdy = 1.0 / ddy
                    tmy = t + (cy + 1.0 - py) * tdy
                elif ddy < 0.0:
                    sy = -1
                    tdy = -1.0 / ddy
                    tmy = t + (py - cy) * tdy
                else:
                    sy = 0
                    tmy = math.inf
                fresh = False
            k = cy * wp + cx
            c = codes[k]
            if c == 1:
                result = t
                break
            if c != 0:
                break
            clr = clearance[k]
            if clr >= 1.0:
                t += clr
                fresh = True
                continue
            if tmx < tmy:
                t = tmx
                tmx += tdx
                cx += sx
            else:
                t = tmy
                tmy += tdy
                cy += sy
        out[i] = result if result <= max_t_cells else math.inf
