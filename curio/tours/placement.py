"""Can the rover stand here? The map check behind "a stop outside the map or in a wall".

:class:`MapPlacement` answers ``check(x_m, y_m)`` (a point in ``map``, metres) with None when the
rover fits there, else the reason as a phrase: outside the map (with the map's bounds), inside
an obstacle, in an unmapped part, or closer to an obstacle than the rover's inscribed radius
(no heading could fit it: the planner's lethal inflation uses the same radius). It uses the
static map, not the live costmap: a visitor standing on a stop while it is edited must not make
the stop invalid. The distance map is computed once per map (a new grid object from mapping is
noticed).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from curio.core.distance import distance_to_features
from curio.estimation.maps import OccupancyGrid

__all__ = ["MapPlacement"]


class MapPlacement:
    """Checks points of ``map`` against an occupancy grid.

    Args:
        grid: the map, or a callable returning the current map (it may be replaced).
        clearance_m: the least distance from an obstacle (the rover's inscribed radius).
    """

    def __init__(self, grid: OccupancyGrid | Callable[[], OccupancyGrid],
                 clearance_m: float) -> None:
        self._grid_of = grid if callable(grid) else (lambda: grid)
        self.clearance_m = clearance_m
        self._cached: OccupancyGrid | None = None
        self._distance_m: npt.NDArray[np.float64] = np.zeros((0, 0))

    def _distances(self, grid: OccupancyGrid) -> npt.NDArray[np.float64]:
        if grid is not self._cached:
            occupied = grid.occupied_mask()
            if occupied.any():
                dist = distance_to_features(occupied) * grid.resolution_m
            else:
                dist = np.full(occupied.shape, np.inf)
            self._distance_m = np.asarray(dist, dtype=np.float64)
            self._cached = grid
        return self._distance_m

    def bounds(self) -> tuple[float, float, float, float]:
        """The map's extent ``(x_min, y_min, x_max, y_max)`` in metres (unrotated origin)."""
        grid = self._grid_of()
        width_m, height_m = grid.size_m
        return (grid.origin.x, grid.origin.y, grid.origin.x + width_m, grid.origin.y + height_m)

    def __call__(self, x_m: float, y_m: float) -> str | None:
        """None when the rover can stand at (x, y), else why not."""
        grid = self._grid_of()
        row, col = grid.world_to_cell(x_m, y_m)
        if not grid.in_bounds(row, col):
            x0, y0, x1, y1 = self.bounds()
            return (f"is outside the map (the map spans x {x0:g} to {x1:g} m and y {y0:g} to "
                    f"{y1:g} m)")
        if int(grid.data[row, col]) >= round(grid.occupied_thresh * 100):
            return "is inside an obstacle on the map (a wall or furniture)"
        if grid.data[row, col] < 0:
            return "is in an unmapped part of the map"
        distance = float(self._distances(grid)[row, col])
        if distance < self.clearance_m:
            return (f"is too close to an obstacle ({distance:.2f} m from it; the rover needs "
                    f"{self.clearance_m:.2f} m)")
        return None
