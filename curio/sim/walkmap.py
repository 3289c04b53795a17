"""Where simulated visitors can walk: clearance, the nearest wall, routes and points of interest.

A :class:`WalkMap` is built once per world from its occupancy grid (``map`` metres):

* **clearance** — the distance (m) from each fine cell to the nearest occupied or unknown cell
  or the map's edge (visitors keep to known free space), with the nearest such cell for the
  wall force of the social-force model;
* **a walking graph** — a coarse grid (``res_m``, 0.2 m) of the cells with at least
  ``walk_clearance_m`` of clearance, 8-connected (no corner cutting), each step weighted a
  little more where the way is narrow, so routes keep to the middle of corridors;
* **routes** — for a destination, the shortest-path tree towards it (``scipy``'s Dijkstra,
  computed when first asked for and kept); :meth:`WalkMap.steer_point` follows that tree from
  a visitor's position and returns the farthest point along it that the visitor can walk to
  in a straight line (line of sight with clearance), so visitors walk straight across open
  rooms and round corners and through doorways as the route bends;
* **points of interest** — the given ones that lie in the main walkable area, plus points
  spread over it (farthest-point sampling from the seed) where visitors go and groups stand;
* **spawn points** for the visitors.

The main walkable area is the connected part of the graph that holds ``anchor`` (the rover's
start), or the largest part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from curio.estimation.maps import OccupancyGrid
from curio.sim.crowd_kernel import segment_min_clearance

__all__ = ["WalkMap"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

_NEIGHBOURS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2.0)), (1, -1, math.sqrt(2.0)))


@dataclass(frozen=True)
class _Tree:
    """A shortest-path tree towards one destination node: ``pred[n]`` is the next node from
    ``n`` (−9999 at the destination and where it cannot be reached)."""

    dest: int
    pred: I64


class WalkMap:
    """Pedestrian geometry of a map (see the module docstring).

    Args:
        grid: the world's occupancy grid (its origin must not be rotated).
        walk_clearance_m: centres of walkable coarse cells keep this far from obstacles.
        res_m: the walking graph's cell size.
        anchor: a point in ``map`` inside the area that matters (the rover's start).
    """

    def __init__(self, grid: OccupancyGrid, walk_clearance_m: float = 0.25,
                 res_m: float = 0.2, anchor: tuple[float, float] | None = None) -> None:
        if abs(grid.origin.yaw) > 1e-9:
            raise ValueError("a WalkMap needs a map whose origin is not rotated")
        self.grid = grid
        self.res_fine = float(grid.resolution_m)
        self.ox, self.oy = grid.origin.x, grid.origin.y
        blocked = ~grid.free_mask() | grid.edge_mask()
        dist, idx = ndimage.distance_transform_edt(~blocked, return_indices=True)
        # Distance from a cell centre to the nearest blocked cell's edge (half a cell nearer
        # than its centre).
        self.clearance_fine: F64 = np.maximum(
            np.asarray(dist, dtype=np.float64) * self.res_fine - 0.5 * self.res_fine, 0.0)
        # Row and column of each fine cell's nearest blocked cell (the crowd's wall lookups).
        self.near_row: I64 = np.ascontiguousarray(idx[0], dtype=np.int64)
        self.near_col: I64 = np.ascontiguousarray(idx[1], dtype=np.int64)
        self.res_m = res_m
        self.walk_clearance_m = walk_clearance_m
        h, w = grid.height, grid.width
        self.ch = max(1, int(h * self.res_fine / res_m))
        self.cw = max(1, int(w * self.res_fine / res_m))
        centres = self.node_xy(np.arange(self.ch * self.cw))
        self.node_clearance: F64 = self.clearance_at(centres)
        self.walkable = self.node_clearance >= walk_clearance_m
        self.graph = self._build_graph()
        self._trees: dict[int, _Tree] = {}
        _, labels = connected_components(self.graph, directed=False)
        self.labels: I64 = np.asarray(labels, dtype=np.int64)
        self.main_label = self._main_label(anchor)
        self.main = self.walkable & (self.labels == self.main_label)

    # -- geometry ----------------------------------------------------------------------------
    def _fine_index(self, xy: F64) -> tuple[I64, I64, npt.NDArray[np.bool_]]:
        col = np.floor((xy[:, 0] - self.ox) / self.res_fine).astype(np.int64)
        row = np.floor((xy[:, 1] - self.oy) / self.res_fine).astype(np.int64)
        inside = (row >= 0) & (row < self.grid.height) & (col >= 0) & (col < self.grid.width)
        return np.where(inside, row, 0), np.where(inside, col, 0), inside

    def clearance_at(self, xy: F64) -> F64:
        """Clearance (m) at each ``(N, 2)`` map point; 0 outside the map."""
        row, col, inside = self._fine_index(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        out: F64 = np.where(inside, self.clearance_fine[row, col], 0.0)
        return out

    def nearest_wall(self, xy: F64) -> F64:
        """The centre of the nearest occupied or unknown cell to each map point, ``(N, 2)``."""
        row, col, _ = self._fine_index(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        nr, nc = self.near_row[row, col], self.near_col[row, col]
        return np.stack([self.ox + (nc + 0.5) * self.res_fine,
                         self.oy + (nr + 0.5) * self.res_fine], axis=1)

    def segment_clear(self, a: tuple[float, float], b: tuple[float, float],
                      clearance_m: float) -> bool:
        """Whether every point of the segment a→b has at least ``clearance_m`` of clearance."""
        return bool(segment_min_clearance(self.clearance_fine, self.ox, self.oy, self.res_fine,
                                          a[0], a[1], b[0], b[1], clearance_m))

    # -- the walking graph -------------------------------------------------------------------
    def node_xy(self, nodes: I64 | npt.NDArray[np.intp]) -> F64:
        """Map coordinates of coarse node centres."""
        nodes = np.asarray(nodes, dtype=np.int64)
        r, c = nodes // self.cw, nodes % self.cw
        return np.stack([self.ox + (c + 0.5) * self.res_m, self.oy + (r + 0.5) * self.res_m],
                        axis=1)

    def node_at(self, x_m: float, y_m: float) -> int:
        """The walkable node of the main area nearest to map point (x, y)."""
        c = math.floor((x_m - self.ox) / self.res_m)
        r = math.floor((y_m - self.oy) / self.res_m)
        if 0 <= r < self.ch and 0 <= c < self.cw and self.main[r * self.cw + c]:
            return r * self.cw + c
        return self._nearest_main(x_m, y_m)

    def _nearest_main(self, x_m: float, y_m: float) -> int:
        nodes = np.flatnonzero(self.main)
        xy = self.node_xy(nodes)
        return int(nodes[int(np.argmin(np.hypot(xy[:, 0] - x_m, xy[:, 1] - y_m)))])

    def _build_graph(self) -> csr_matrix:
        h, w = self.ch, self.cw
        ok = self.walkable.reshape(h, w)
        clr = self.node_clearance.reshape(h, w)
        rows: list[I64] = []
        cols: list[I64] = []
        weights: list[F64] = []
        ids = np.arange(h * w, dtype=np.int64).reshape(h, w)
        for dr, dc, step in _NEIGHBOURS:
            r0, r1 = max(0, -dr), h - max(0, dr)
            c0, c1 = max(0, -dc), w - max(0, dc)
            a = (slice(r0, r1), slice(c0, c1))
            b = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
            both = ok[a] & ok[b]
            if dr and dc:  # no corner cutting
                both &= ok[r0 + dr:r1 + dr, c0:c1] & ok[r0:r1, c0 + dc:c1 + dc]
            narrow = np.minimum(clr[a], clr[b])
            cost = step * self.res_m * (1.0 + 0.5 * np.clip(0.8 - narrow, 0.0, None) / 0.8)
            rows.append(ids[a][both])
            cols.append(ids[b][both])
            weights.append(cost[both])
        r = np.concatenate(rows)
        c = np.concatenate(cols)
        wts = np.concatenate(weights)
        n = h * w
        return csr_matrix((np.concatenate([wts, wts]), (np.concatenate([r, c]),
                                                          np.concatenate([c, r]))), shape=(n, n))

    def _main_label(self, anchor: tuple[float, float] | None) -> int:
        walk_labels = self.labels[self.walkable]
        if len(walk_labels) == 0:
            raise ValueError("the map has no place where a person can walk")
        if anchor is not None:
            c = math.floor((anchor[0] - self.ox) / self.res_m)
            r = math.floor((anchor[1] - self.oy) / self.res_m)
            win = [(rr, cc) for rr in range(r - 3, r + 4) for cc in range(c - 3, c + 4)
                   if 0 <= rr < self.ch and 0 <= cc < self.cw and self.walkable[rr * self.cw + cc]]
            if win:
                rr, cc = min(win, key=lambda p: (p[0] - r) ** 2 + (p[1] - c) ** 2)
                return int(self.labels[rr * self.cw + cc])
        counts = np.bincount(walk_labels)
        return int(np.argmax(counts))

    # -- routes ------------------------------------------------------------------------------
    def tree_to(self, dest: int, limit_m: float = np.inf) -> _Tree:
        """The shortest-path tree towards node ``dest`` (kept for reuse unless limited)."""
        tree = self._trees.get(dest) if math.isinf(limit_m) else None
        if tree is None:
            _, pred = dijkstra(self.graph, directed=False, indices=dest,
                               return_predecessors=True, limit=limit_m)
            tree = _Tree(dest, np.asarray(pred, dtype=np.int64))
            if math.isinf(limit_m):
                self._trees[dest] = tree
        return tree

    def steer_point(self, tree: _Tree, x_m: float, y_m: float,
                    look_m: float = 3.0, clearance_m: float = 0.2) -> tuple[float, float]:
        """Where to head for along ``tree`` from map point (x, y): the farthest node within
        ``look_m`` of path that is in straight-line reach (else the next node)."""
        node = self.node_at(x_m, y_m)
        chain = [node]
        steps = max(1, int(look_m / self.res_m))
        pred = tree.pred
        for _ in range(steps):
            nxt = int(pred[chain[-1]])
            if nxt < 0:
                break
            chain.append(nxt)
        xy = self.node_xy(np.asarray(chain))
        if len(chain) == 1:
            return float(xy[0, 0]), float(xy[0, 1])
        for k in range(len(chain) - 1, 0, -1):
            if self.segment_clear((x_m, y_m), (float(xy[k, 0]), float(xy[k, 1])), clearance_m):
                return float(xy[k, 0]), float(xy[k, 1])
        return float(xy[1, 0]), float(xy[1, 1])

    def route_length_m(self, a: tuple[float, float], b: tuple[float, float]) -> float:
        """Length (m) of the walking route from a to b (inf if there is none)."""
        dist = dijkstra(self.graph, directed=False, indices=self.node_at(*b))
        return float(dist[self.node_at(*a)])

    # -- places ------------------------------------------------------------------------------
    def points_of_interest(self, rng: np.random.Generator, given: list[tuple[float, float]],
                           count: int | None = None,
                           min_clearance_m: float = 0.7) -> list[tuple[float, float]]:
        """``given`` points that lie in the main area, plus points spread over it.

        The extra points have ``min_clearance_m`` of clearance (rooms and wide corridors) and
        are chosen by farthest-point sampling; ``count`` (default: one per 25 m² of the main
        area, 4..24) is the total.
        """
        out: list[tuple[float, float]] = []
        for x, y in given:
            nx, ny = self.node_xy(np.array([self.node_at(x, y)]))[0]
            if math.hypot(nx - x, ny - y) < 1.0:
                out.append((float(x), float(y)))
        area = float(self.main.sum()) * self.res_m ** 2
        total = count if count is not None else int(np.clip(round(area / 25.0), 4, 24))
        cand = np.flatnonzero(self.main & (self.node_clearance >= min_clearance_m))
        if len(cand) == 0:
            cand = np.flatnonzero(self.main)
        xy = self.node_xy(cand)
        if out:
            ref = np.array(out)
            dmin = np.min(np.hypot(xy[:, None, 0] - ref[None, :, 0],
                                   xy[:, None, 1] - ref[None, :, 1]), axis=1)
        else:
            first = int(rng.integers(len(cand)))
            out.append((float(xy[first, 0]), float(xy[first, 1])))
            dmin = np.hypot(xy[:, 0] - xy[first, 0], xy[:, 1] - xy[first, 1])
        while len(out) < total and dmin.max() > 1.5:
            k = int(np.argmax(dmin))
            out.append((float(xy[k, 0]), float(xy[k, 1])))
            dmin = np.minimum(dmin, np.hypot(xy[:, 0] - xy[k, 0], xy[:, 1] - xy[k, 1]))
        return out

    def spawn_points(self, rng: np.random.Generator, n: int, away_from: tuple[float, float],
                     min_away_m: float = 2.0, spacing_m: float = 0.7,
                     min_clearance_m: float = 0.4) -> list[tuple[float, float]]:
        """``n`` places to start visitors: in the main area, ``min_away_m`` from
        ``away_from`` and ``spacing_m`` from each other (fewer if the map is too small)."""
        cand = np.flatnonzero(self.main & (self.node_clearance >= min_clearance_m))
        xy = self.node_xy(cand)
        far = np.hypot(xy[:, 0] - away_from[0], xy[:, 1] - away_from[1]) >= min_away_m
        xy = xy[far] if far.any() else xy
        order = rng.permutation(len(xy))
        out: list[tuple[float, float]] = []
        for k in order:
            p = (float(xy[k, 0]), float(xy[k, 1]))
            if all(math.hypot(p[0] - q[0], p[1] - q[1]) >= spacing_m for q in out):
                out.append(p)
                if len(out) == n:
                    break
        return out
