"""How far a rover has to drive to a point, on the shared map (for "the nearest rover").

:class:`RouteDistances` keeps a coarse grid (``cell_m``) of the places the rover's centre can
be (free cells further than the inscribed radius from any wall or unknown cell) as an
8-connected graph, and answers distance queries with Dijkstra from the goal
(:func:`scipy.sparse.csgraph.dijkstra`, cached per goal cell). A point off the graph is moved
to the nearest cell on it; unreachable is ``inf``. Straight lines would pick a rover on the
other side of a wall; this costs a few milliseconds per new goal.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import dijkstra

from curio.estimation.maps import OccupancyGrid

__all__ = ["RouteDistances"]


class RouteDistances:
    """Driving distances on ``grid`` (see the module docstring).

    Args:
        grid: the shared map.
        radius_m: the rover's inscribed radius (keeps the centre off the walls).
        cell_m: the coarse cell size.
    """

    def __init__(self, grid: OccupancyGrid, radius_m: float, cell_m: float = 0.2) -> None:
        self.cell_m = cell_m
        self.origin = (grid.origin.x, grid.origin.y)
        blocked = grid.occupied_mask() | grid.unknown_mask()
        clearance = ndimage.distance_transform_edt(~blocked) * grid.resolution_m
        factor = max(1, round(cell_m / grid.resolution_m))
        h, w = clearance.shape[0] // factor, clearance.shape[1] // factor
        coarse = clearance[:h * factor, :w * factor].reshape(h, factor, w, factor).min(axis=(1, 3))
        self.free = coarse > radius_m
        self.shape = (h, w)
        self._index = -np.ones((h, w), dtype=np.int64)
        cells = np.argwhere(self.free)
        self._index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
        self._cells = cells
        self._graph = self._build_graph()
        self._cache: dict[int, npt.NDArray[np.float64]] = {}

    def _build_graph(self) -> csr_matrix:
        rows, cols, weights = [], [], []
        idx = self._index
        h, w = self.shape
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = idx[0:h - dr, max(0, -dc):w - max(0, dc)]
            b = idx[dr:h, max(0, dc):w - max(0, -dc)]
            ok = (a >= 0) & (b >= 0)
            length = math.hypot(dr, dc) * self.cell_m
            rows.append(a[ok])
            cols.append(b[ok])
            weights.append(np.full(int(ok.sum()), length))
        r = np.concatenate(rows)
        c = np.concatenate(cols)
        wts = np.concatenate(weights)
        n = len(self._cells)
        both = coo_matrix((np.concatenate([wts, wts]), (np.concatenate([r, c]),
                                                        np.concatenate([c, r]))), shape=(n, n))
        return both.tocsr()

    def _node(self, x_m: float, y_m: float) -> tuple[int, float]:
        """The graph node nearest (x, y) and how far that is, metres."""
        if len(self._cells) == 0:
            return -1, math.inf
        col = (x_m - self.origin[0]) / self.cell_m - 0.5
        row = (y_m - self.origin[1]) / self.cell_m - 0.5
        d = np.hypot(self._cells[:, 0] - row, self._cells[:, 1] - col)
        k = int(np.argmin(d))
        return k, float(d[k]) * self.cell_m

    def distance(self, start: tuple[float, float], goal: tuple[float, float]) -> float:
        """Driving distance from ``start`` to ``goal`` (map metres); ``inf`` when unreachable."""
        g, dg = self._node(*goal)
        s, ds = self._node(*start)
        if g < 0 or s < 0:
            return math.inf
        field = self._cache.get(g)
        if field is None:
            field = np.asarray(dijkstra(self._graph, indices=g), dtype=np.float64)
            self._cache[g] = field
        return float(field[s]) + dg + ds
