"""Global planner: cost-aware weighted A* on the costmap, then shortcutting and smoothing.

The search runs on the 8-connected costmap grid (diagonal steps cost √2) with the octile
heuristic, in compiled code (:mod:`curio.nav.planner_kernels`). A cell's traversal cost per
metre is ``1 + cost_penalty · cost / 252`` so paths keep away from walls; cells of cost 253
(inscribed) and above are not traversable (unknown, 255, only with ``allow_unknown``). The grid
path is then shortcut along straight segments that are collision-free *and no more expensive*
than the grid path they replace, resampled every ``path_step_m`` and lightly smoothed (a point
that would move into a higher cost is left where it was). Headings follow the path; the last
pose carries the goal's heading (a NaN goal heading means "any": it keeps the path's).

Errors are the typed :mod:`curio.nav.api` ones with a sentence saying where and why:
:class:`StartOutsideMapError`, :class:`StartBlockedError`, :class:`GoalOutsideMapError`,
:class:`GoalBlockedError` (from the goal validator the navigator uses too,
:mod:`curio.nav.validation`), :class:`NoPathError`. With ``goal_nearest_free`` a blocked goal
is moved to the nearest traversable cell within ``goal_nearest_free_max_m``.

:meth:`GlobalPlanner.plan` keeps no state between calls and releases the GIL in its search,
so it is meant to run in a worker thread (``asyncio.to_thread``) while the loop goes on.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.config import PlannerConfig
from curio.core.geometry import Pose2D, wrap_angle
from curio.nav import planner_kernels as kern
from curio.nav.api import NoPathError
from curio.nav.costs import INSCRIBED, LETHAL, MAX_NON_OBSTACLE, NO_INFORMATION, cost_at_distance
from curio.nav.validation import Endpoints, GoalValidator, passable_costs

__all__ = ["GlobalPlanner", "PlanResult", "narrow_cost", "path_length_m", "traversal_lut"]

U8Array = npt.NDArray[np.uint8]
FloatArray = npt.NDArray[np.float64]



def traversal_lut(cost_penalty: float, allow_unknown: bool, narrow_cost: int | None = None,
                  narrow_penalty: float = 0.0) -> FloatArray:
    """Traversal cost per cell length for each costmap value (−1 = not traversable).

    With ``narrow_cost`` (the cost at the footprint's circumscribed radius from an obstacle),
    values from it up to 252 cost up to ``narrow_penalty`` more, rising linearly: the path
    crosses a narrow passage straight and centred (where a misaligned square footprint may
    not fit) instead of cutting into it at an angle.
    """
    lut = 1.0 + cost_penalty * np.arange(256, dtype=np.float64) / MAX_NON_OBSTACLE
    if narrow_cost is not None and 0 < narrow_cost < INSCRIBED and narrow_penalty > 0.0:
        v = np.arange(narrow_cost, INSCRIBED, dtype=np.float64)
        lut[narrow_cost:INSCRIBED] += narrow_penalty * (v - narrow_cost + 1.0) / (
            INSCRIBED - narrow_cost)
    lut[NO_INFORMATION] = 1.0 + cost_penalty * 0.5
    lut[~passable_costs(allow_unknown)] = -1.0
    return lut


def narrow_cost(inscribed_m: float, circumscribed_m: float, cost_scaling_factor: float) -> int:
    """Costmap value at ``circumscribed_m`` from an obstacle (:mod:`curio.nav.costs`): nearer
    than that, a footprint that is not round may not fit when misaligned."""
    return int(cost_at_distance(circumscribed_m - inscribed_m, cost_scaling_factor))


def path_length_m(poses: list[Pose2D]) -> float:
    """Length of a path along its poses, metres."""
    return float(sum(a.distance_to(b) for a, b in itertools.pairwise(poses)))


def _read_only_grid(costs: U8Array, resolution_m: float) -> U8Array:
    """``costs`` as a contiguous read-only uint8 view (one compiled signature for every
    caller; never written), after checking the grid and the resolution."""
    costs = np.ascontiguousarray(costs, dtype=np.uint8).view()
    if costs.ndim != 2 or costs.size == 0:
        raise ValueError(f"costs must be a non-empty 2-D uint8 grid, got shape {costs.shape}")
    costs.setflags(write=False)
    if not resolution_m > 0.0:
        raise ValueError(f"resolution_m must be > 0, got {resolution_m}")
    return costs


def _polyline_length(xy: FloatArray) -> float:
    if xy.shape[0] < 2:
        return 0.0
    d = np.diff(xy, axis=0)
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


@dataclass(frozen=True)
class PlanResult:
    """A plan with the figures that describe it.

    Attributes:
        poses: the path in ``map`` (start → goal), headings along the path.
        length_m: its length.
        cost: traversal cost of the grid path found by A* (cells × cost factor).
        expansions: cells expanded by the search.
        goal: the goal actually planned to (differs from the request when moved to free space).
        goal_moved: whether the goal was moved to the nearest free cell.
        grid_path: ``(N, 2)`` ``(row, col)`` cells of the raw A* path.
    """

    poses: list[Pose2D]
    length_m: float
    cost: float
    expansions: int
    goal: Pose2D
    goal_moved: bool
    grid_path: npt.NDArray[np.int64]


class GlobalPlanner:
    """Plans collision-free, smoothed paths on a costmap grid (thread-safe, stateless)."""

    def __init__(self, cfg: PlannerConfig, *, escape_radius_m: float = 0.35,
                 narrow_cost: int | None = None) -> None:
        """Args:
        cfg: planner settings.
        escape_radius_m: around the start, cells of cost 253 (inscribed) are traversable
            within this radius so a rover too close to an obstacle can leave (254 never is).
        narrow_cost: the costmap value at the footprint's circumscribed radius from an
            obstacle (see :func:`narrow_cost`); cells at or above it cost up to
            ``cfg.narrow_penalty`` more. None: no such term (a round rover).
        """
        self.cfg = cfg
        self.escape_radius_m = escape_radius_m
        self._lut = traversal_lut(cfg.cost_penalty, cfg.allow_unknown, narrow_cost,
                                  cfg.narrow_penalty)
        self._lut.setflags(write=False)
        self.validator = GoalValidator(cfg)

    def warm_up(self) -> None:
        """Compile the kernels now (first use otherwise pays a few seconds; cached on disk)."""
        costs = np.zeros((8, 8), dtype=np.uint8)
        costs[2:6, 4] = LETHAL
        self.plan(Pose2D(0.05, 0.15), Pose2D(0.35, 0.25), costs, 0.05, Pose2D())

    def plan(self, start: Pose2D, goal: Pose2D, costs: U8Array, resolution_m: float,
             origin: Pose2D) -> list[Pose2D]:
        """Plan from ``start`` to ``goal`` (both in ``map``) on ``costs``.

        Args:
            costs: ``(H, W)`` uint8 costmap (row 0 at the bottom), not modified.
            resolution_m: cell size, metres.
            origin: pose of cell (0, 0)'s lower-left corner in ``map``.

        Returns:
            Poses in ``map`` from the start to the goal, about ``path_step_m`` apart.

        Raises:
            StartOutsideMapError, StartBlockedError, GoalOutsideMapError, GoalBlockedError,
            NoPathError: with a sentence saying where and why.
        """
        return self.plan_detailed(start, goal, costs, resolution_m, origin).poses

    def plan_detailed(self, start: Pose2D, goal: Pose2D, costs: U8Array, resolution_m: float,
                      origin: Pose2D) -> PlanResult:
        """Like :meth:`plan`, returning the figures of the search too."""
        costs = _read_only_grid(costs, resolution_m)
        ends = self.validator.endpoints(start, goal, costs, resolution_m, origin)
        (s_r, s_c), (g_r, g_c) = ends.start_cell, ends.goal_cell
        escape_cells = self.escape_radius_m / resolution_m
        escape_r2 = int(escape_cells * escape_cells) if ends.start_cost == INSCRIBED else 0
        h, w = costs.shape
        g = np.zeros(h * w, dtype=np.float64)
        parent = np.zeros(h * w, dtype=np.uint8)
        found, expansions = kern.astar(costs, self._lut, s_r, s_c, g_r, g_c,
                                       float(self.cfg.heuristic_weight), escape_r2, g, parent)
        if not found:
            raise NoPathError(
                f"no collision-free path from ({start.x:.2f}, {start.y:.2f}) to "
                f"({ends.goal.x:.2f}, {ends.goal.y:.2f}) m: the goal is cut off from the start "
                f"in the costmap ({int(expansions)} reachable cells searched)")
        rows, cols = kern.trace_path(parent, w, g_r, g_c)
        pts = self._path_points(rows, cols, g, costs, resolution_m, ends, escape_r2)
        world = origin.transform_points(pts)
        return PlanResult(poses=_with_headings(world, ends.goal.yaw),
                          length_m=_polyline_length(world), cost=float(g[g_r * w + g_c]),
                          expansions=int(expansions), goal=ends.goal, goal_moved=ends.goal_moved,
                          grid_path=np.stack([rows, cols], axis=1))

    # ------------------------------------------------------------------ helpers
    def _path_points(self, rows: npt.NDArray[np.int64], cols: npt.NDArray[np.int64],
                     g: FloatArray, costs: U8Array, res: float, ends: Endpoints,
                     escape_r2: int) -> FloatArray:
        """The grid path shortcut, resampled every ``path_step_m`` and smoothed, in grid
        metres, from the exact start to the (possibly moved) goal."""
        w = costs.shape[1]
        if self.cfg.smooth and rows.shape[0] > 2:
            max_span = max(8, round(20.0 / res))
            keep = kern.shortcut(costs, self._lut, rows, cols, g, w, escape_r2, 12, max_span)
            vr, vc = rows[keep], cols[keep]
        else:
            vr, vc = rows, cols
        # Vertices in grid metres (cell centres), with the exact start and goal at the ends.
        verts = np.stack([(vc + 0.5) * res, (vr + 0.5) * res], axis=1)
        verts = verts.astype(np.float64)
        if verts.shape[0] == 1:
            verts = np.vstack([verts, verts])
        verts[0] = ends.start_xy
        verts[-1] = ends.goal_xy
        pts = _resample(verts, self.cfg.path_step_m)
        if self.cfg.smooth and pts.shape[0] > 4:
            pts = self._smooth(pts, costs, res, *ends.start_cell, escape_r2)
        return pts

    def _smooth(self, pts: FloatArray, costs: U8Array, res: float, s_r: int, s_c: int,
                escape_r2: int) -> FloatArray:
        """A few gradient steps pulling points towards their neighbours' mean (ends fixed).

        A point whose cell would become more expensive than where it started stays put.
        """
        h, w = costs.shape
        orig = pts.copy()
        cur = pts.copy()
        cells = np.floor(orig / res).astype(np.int64)
        cells[:, 0] = np.clip(cells[:, 0], 0, w - 1)
        cells[:, 1] = np.clip(cells[:, 1], 0, h - 1)
        orig_cost = costs[cells[:, 1], cells[:, 0]].astype(np.int32)
        for _ in range(8):
            nxt = cur.copy()
            nxt[1:-1] += 0.1 * (orig[1:-1] - cur[1:-1]) \
                + 0.4 * (cur[:-2] + cur[2:] - 2.0 * cur[1:-1])
            cur = nxt
        cc = np.floor(cur / res).astype(np.int64)
        inside = (cc[:, 0] >= 0) & (cc[:, 0] < w) & (cc[:, 1] >= 0) & (cc[:, 1] < h)
        cc[:, 0] = np.clip(cc[:, 0], 0, w - 1)
        cc[:, 1] = np.clip(cc[:, 1], 0, h - 1)
        new_cost = costs[cc[:, 1], cc[:, 0]].astype(np.int32)
        ok = inside & (new_cost <= np.maximum(orig_cost, 0)) & (self._lut[new_cost] >= 0)
        if escape_r2 > 0:
            near = (cc[:, 1] - s_r) ** 2 + (cc[:, 0] - s_c) ** 2 <= escape_r2
            ok |= inside & near & (new_cost <= INSCRIBED) & (new_cost <= orig_cost)
        ok[0] = ok[-1] = True
        cur[~ok] = orig[~ok]
        cur[0], cur[-1] = orig[0], orig[-1]
        # Segments between moved points must stay traversable too: put back the ends of any
        # segment that is not, until all are.
        for _ in range(6):
            rc = np.stack([cur[:, 1] / res - 0.5, cur[:, 0] / res - 0.5], axis=1)
            seg_ok = kern.segments_clear(costs, self._lut, rc, escape_r2, s_r, s_c)
            if seg_ok.all():
                return cur
            bad = np.zeros(cur.shape[0], dtype=bool)
            bad[:-1] |= ~seg_ok
            bad[1:] |= ~seg_ok
            cur[bad] = orig[bad]
        return orig


def _resample(verts: FloatArray, step_m: float) -> FloatArray:
    """Points along a polyline every ``step_m`` (vertices kept, ends exact)."""
    out = [verts[:1]]
    for a, b in itertools.pairwise(verts):
        seg = float(np.hypot(*(b - a)))
        if seg <= 1e-12:
            continue
        k = max(1, math.ceil(seg / step_m))
        t = (np.arange(1, k + 1, dtype=np.float64) / k)[:, None]
        out.append(a + t * (b - a))
    return np.concatenate(out, axis=0)


def _with_headings(world: FloatArray, goal_yaw: float) -> list[Pose2D]:
    """Poses along the points, heading along the path; the last takes ``goal_yaw`` when it is
    finite (a NaN goal heading means "any": the last pose keeps the path's direction)."""
    n = world.shape[0]
    if n == 1:
        yaw = wrap_angle(goal_yaw) if math.isfinite(goal_yaw) else 0.0
        return [Pose2D(float(world[0, 0]), float(world[0, 1]), yaw)]
    nxt = np.vstack([world[1:], world[-1:]])
    prv = np.vstack([world[:1], world[:-1]])
    d = nxt - prv
    yaws = np.arctan2(d[:, 1], d[:, 0])
    yaws[yaws >= np.pi] -= 2.0 * np.pi  # [-π, π) like wrap_angle
    if math.isfinite(goal_yaw):
        yaws[-1] = wrap_angle(goal_yaw)
    return list(map(Pose2D, world[:, 0].tolist(), world[:, 1].tolist(), yaws.tolist()))
