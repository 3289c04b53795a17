"""Cell edits of a map, as the editor sends them, and the grid as the editor reads it.

The editor paints on a copy of the grid in the browser (undo and redo are its own) and sends
only what changed, as runs along rows: ``[row, col, length, value]`` — row 0 is the *bottom*
row (lowest y, as in :class:`~curio.estimation.maps.OccupancyGrid`), ``value`` is −1 unknown,
0 free or 100 occupied. A brush stroke is a few runs per row, so an edit of thousands of
cells stays well inside ``web.max_message_bytes``.

The grid is sent to the editor as ``cells``: base64 of one byte per cell, rows from the bottom,
each byte the occupancy 0..100 or 255 for unknown.
"""

from __future__ import annotations

import base64
from typing import Any

import numpy as np

from curio.estimation.maps import OccupancyGrid
from curio.maps.library import MapLibraryError

__all__ = ["MAX_RUNS", "apply_runs", "grid_json"]

MAX_RUNS = 20000
VALUES = (-1, 0, 100)


def grid_json(grid: OccupancyGrid) -> dict[str, Any]:
    """The grid for the editor (and the live view while mapping): size, resolution, origin
    and the cells (see the module docstring)."""
    raw = np.where(grid.data < 0, 255, np.clip(grid.data, 0, 100)).astype(np.uint8)
    o = grid.origin
    return {"width": grid.width, "height": grid.height, "resolution_m": grid.resolution_m,
            "origin": [o.x, o.y, o.yaw],
            "cells": base64.b64encode(np.ascontiguousarray(raw).tobytes()).decode("ascii")}


def apply_runs(grid: OccupancyGrid, runs: Any) -> tuple[OccupancyGrid, int]:
    """A copy of ``grid`` with ``runs`` painted; return it and how many cells changed.

    Raises:
        MapLibraryError: a run that is not four whole numbers, leaves the grid or paints a
            value other than −1, 0 or 100; too many runs; nothing to change.
    """
    if not isinstance(runs, list) or not runs:
        raise MapLibraryError("changes must be a non-empty list of [row, col, length, value] "
                              "runs")
    if len(runs) > MAX_RUNS:
        raise MapLibraryError(f"{len(runs)} runs is too many in one save: at most {MAX_RUNS}")
    out = grid.copy()
    before = grid.data
    for i, run in enumerate(runs):
        if not (isinstance(run, list) and len(run) == 4 and all(
                isinstance(v, int) and not isinstance(v, bool) for v in run)):
            raise MapLibraryError(f"change {i} must be [row, col, length, value] (four whole "
                                  f"numbers), got {str(run)[:60]}")
        row, col, length, value = run
        if value not in VALUES:
            raise MapLibraryError(f"change {i}: value {value} is not allowed: -1 (unknown), "
                                  "0 (free) or 100 (occupied)")
        if not (0 <= row < grid.height and col >= 0 and length >= 1
                and col + length <= grid.width):
            raise MapLibraryError(
                f"change {i}: row {row}, columns {col}..{col + length - 1} leave the map "
                f"({grid.height} rows × {grid.width} columns)")
        out.data[row, col:col + length] = value
    changed = int(np.count_nonzero(out.data != before))
    return out, changed
