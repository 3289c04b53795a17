"""One goal validator: may the rover start here, may it be sent there (``map``, metres).

The navigator checks every goal it is sent before accepting it, and the planner checks its
start and goal before it searches. Both use :class:`GoalValidator`, so a goal is rejected at
once exactly when the planner would refuse it (as to where it lies):

* the position must be finite;
* it must lie on the cost grid;
* a goal's cell must be passable (``INSCRIBED`` and ``LETHAL`` never are, ``NO_INFORMATION``
  only with ``nav.planner.allow_unknown``), or, with ``goal_nearest_free``, a passable cell
  must lie within ``goal_nearest_free_max_m`` (the planner moves the goal there);
* a start's cell may be ``INSCRIBED`` (the rover may drive out of it), never ``LETHAL`` (nor
  unknown without ``allow_unknown``).

The two callers word their errors for their own readers: the navigator for the operator who
sent the goal (:meth:`GoalValidator.check_goals`, naming the waypoint and the config key), the
planner for its caller (:meth:`GoalValidator.endpoints`). Grids are ``(H, W)`` uint8 costs with
row 0 at the bottom; ``origin`` is the pose of cell (0, 0)'s lower-left corner in ``map``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.config import PlannerConfig
from curio.core.geometry import Pose2D
from curio.nav.api import (
    GoalBlockedError,
    GoalOutsideMapError,
    InvalidGoalError,
    StartBlockedError,
    StartOutsideMapError,
)
from curio.nav.costs import INSCRIBED, LETHAL, NO_INFORMATION

__all__ = ["Endpoints", "GoalValidator", "grid_extent", "passable_costs"]

U8Array = npt.NDArray[np.uint8]
BoolArray = npt.NDArray[np.bool_]
Cell = tuple[int, int]


def passable_costs(allow_unknown: bool) -> BoolArray:
    """Which of the 256 cost values a path may cross: all below ``INSCRIBED``, and
    ``NO_INFORMATION`` when ``allow_unknown``."""
    ok = np.ones(256, dtype=bool)
    ok[INSCRIBED] = ok[LETHAL] = False
    ok[NO_INFORMATION] = allow_unknown
    return ok


def grid_extent(origin: Pose2D, resolution_m: float, h: int, w: int) -> str:
    """Where a grid lies, in words (for error messages)."""
    if origin.yaw == 0.0:
        return (f"x {origin.x:.2f}..{origin.x + w * resolution_m:.2f} m, "
                f"y {origin.y:.2f}..{origin.y + h * resolution_m:.2f} m")
    return f"{w} × {h} cells of {resolution_m:g} m from ({origin.x:.2f}, {origin.y:.2f}) m"


def _finite(p: Pose2D) -> bool:
    return math.isfinite(p.x) and math.isfinite(p.y)


@dataclass(frozen=True)
class Endpoints:
    """Where a plan starts and ends on the grid (see :meth:`GoalValidator.endpoints`).

    Attributes:
        start_cell, goal_cell: ``(row, col)``; the goal's is the moved one when it was moved.
        start_cost: the cost under the start (``INSCRIBED`` lets the rover escape).
        start_xy, goal_xy: the exact ends in grid metres (the moved goal: its cell's centre).
        goal: the goal planned to, in ``map`` (the request, or the moved one with its heading).
        goal_moved: whether the goal was moved to the nearest passable cell.
    """

    start_cell: Cell
    start_cost: int
    start_xy: tuple[float, float]
    goal_cell: Cell
    goal_xy: tuple[float, float]
    goal: Pose2D
    goal_moved: bool


class GoalValidator:
    """Checks starts and goals against a cost grid (see the module docstring).

    Args:
        cfg: ``nav.planner`` (``allow_unknown``, ``goal_nearest_free``,
            ``goal_nearest_free_max_m``).
    """

    def __init__(self, cfg: PlannerConfig) -> None:
        self.cfg = cfg
        self.passable = passable_costs(cfg.allow_unknown)
        self.passable.setflags(write=False)

    # --- the shared rules -------------------------------------------------------------------
    @staticmethod
    def grid_xy(p: Pose2D, origin: Pose2D) -> tuple[float, float]:
        """A ``map`` point in grid metres (from cell (0, 0)'s lower-left corner)."""
        return origin.inverse().transform_point(p.x, p.y)

    @staticmethod
    def cell_of(xy: tuple[float, float], resolution_m: float, shape: tuple[int, int]
                ) -> Cell | None:
        """``(row, col)`` of a point in grid metres; None off the grid."""
        r, c = math.floor(xy[1] / resolution_m), math.floor(xy[0] / resolution_m)
        return (r, c) if 0 <= r < shape[0] and 0 <= c < shape[1] else None

    def nearest_free(self, costs: U8Array, r: int, c: int, resolution_m: float) -> Cell | None:
        """The passable cell nearest ``(r, c)`` within ``goal_nearest_free_max_m`` (the
        cheapest of equally near ones); None when there is none or ``goal_nearest_free`` is
        off."""
        if not self.cfg.goal_nearest_free:
            return None
        rad = math.floor(self.cfg.goal_nearest_free_max_m / resolution_m)
        if rad <= 0:
            return None
        h, w = costs.shape
        r0, r1, c0, c1 = max(0, r - rad), min(h, r + rad + 1), max(0, c - rad), min(w, c + rad + 1)
        window = costs[r0:r1, c0:c1]
        free = self.passable[window]
        rr, cc = np.mgrid[r0:r1, c0:c1]
        d2 = (rr - r) ** 2 + (cc - c) ** 2
        free &= d2 <= rad * rad
        if not free.any():
            return None
        # nearest first, then the cheapest among equally near cells
        score = d2.astype(np.float64) + window.astype(np.float64) / 1000.0
        score[~free] = np.inf
        k = int(np.argmin(score))
        return (r0 + k // window.shape[1], c0 + k % window.shape[1])

    # --- the navigator: goals sent by the operator, the tree, a scenario --------------------
    def check_goals(self, seq: list[Pose2D], costs: U8Array, resolution_m: float,
                    origin: Pose2D) -> None:
        """Raise a typed error naming the first unusable pose of a goal or waypoint sequence.

        Raises:
            InvalidGoalError: no pose, or a position that is not finite.
            GoalOutsideMapError: off the grid.
            GoalBlockedError: not passable, with no passable cell near enough.
        """
        if not seq:
            raise InvalidGoalError("a goal needs at least one pose (x, y[, yaw]) in map")
        h, w = costs.shape
        for k, p in enumerate(seq):
            which = "the goal" if len(seq) == 1 else f"waypoint {k + 1} of {len(seq)}"
            if not _finite(p):
                raise InvalidGoalError(f"{which} ({p.x}, {p.y}) is not a finite position")
            cell = self.cell_of(self.grid_xy(p, origin), resolution_m, (h, w))
            if cell is None:
                raise GoalOutsideMapError(f"{which} ({p.x:.2f}, {p.y:.2f}) m is outside the map "
                                          f"({grid_extent(origin, resolution_m, h, w)})")
            cost = int(costs[cell])
            if not self.passable[cost] and self.nearest_free(costs, *cell, resolution_m) is None:
                why = {INSCRIBED: "too close to an obstacle for the rover",
                       LETHAL: "inside an obstacle"}.get(cost, "in unknown space")
                near = self.cfg.goal_nearest_free_max_m if self.cfg.goal_nearest_free else 0.0
                raise GoalBlockedError(
                    f"{which} ({p.x:.2f}, {p.y:.2f}) m is {why}, with no free cell within "
                    f"{near:g} m (nav.planner.goal_nearest_free_max_m)")

    # --- the planner: its start and goal -----------------------------------------------------
    def endpoints(self, start: Pose2D, goal: Pose2D, costs: U8Array, resolution_m: float,
                  origin: Pose2D) -> Endpoints:
        """Where a plan from ``start`` to ``goal`` (``map``) begins and ends on the grid.

        Raises:
            StartOutsideMapError, StartBlockedError, GoalOutsideMapError, GoalBlockedError:
                with a sentence saying where and why.
        """
        if not _finite(start):
            raise StartOutsideMapError(f"the start ({start.x}, {start.y}) is not a finite "
                                       f"position; x and y (m) must be numbers")
        if not _finite(goal):
            raise GoalOutsideMapError(f"the goal ({goal.x}, {goal.y}) is not a finite "
                                      f"position; x and y (m) must be numbers")
        h, w = costs.shape
        extent = grid_extent(origin, resolution_m, h, w)
        sxy = self.grid_xy(start, origin)
        s_cell = self.cell_of(sxy, resolution_m, (h, w))
        if s_cell is None:
            raise StartOutsideMapError(f"the start ({start.x:.2f}, {start.y:.2f}) m is outside "
                                       f"the costmap, which covers {extent}")
        s_cost = int(costs[s_cell])
        if s_cost != INSCRIBED and not self.passable[s_cost]:
            what = "an obstacle" if s_cost == LETHAL else "unknown space"
            raise StartBlockedError(
                f"the start ({start.x:.2f}, {start.y:.2f}) m is in {what} (cost {s_cost}); "
                f"clear the costmap around the rover or move it away")
        gxy = self.grid_xy(goal, origin)
        g_cell = self.cell_of(gxy, resolution_m, (h, w))
        if g_cell is None:
            raise GoalOutsideMapError(f"the goal ({goal.x:.2f}, {goal.y:.2f}) m is outside "
                                      f"the costmap, which covers {extent}")
        if self.passable[costs[g_cell]]:
            return Endpoints(s_cell, s_cost, sxy, g_cell, gxy, goal, False)
        moved = self._moved_goal(goal, costs, g_cell, resolution_m)
        gxy = ((moved[1] + 0.5) * resolution_m, (moved[0] + 0.5) * resolution_m)
        cx, cy = origin.transform_point(*gxy)
        return Endpoints(s_cell, s_cost, sxy, moved, gxy, Pose2D(cx, cy, goal.yaw), True)

    def _moved_goal(self, goal: Pose2D, costs: U8Array, cell: Cell, resolution_m: float) -> Cell:
        """The passable cell a blocked goal moves to, or the planner's GoalBlockedError."""
        moved = self.nearest_free(costs, *cell, resolution_m)
        if moved is not None:
            return moved
        why = {INSCRIBED: "too close to an obstacle for the rover (inscribed cost 253)",
               LETHAL: "inside an obstacle (cost 254)",
               NO_INFORMATION: "in unknown space (cost 255)"}[int(costs[cell])]
        extra = (f" and no free cell lies within goal_nearest_free_max_m="
                 f"{self.cfg.goal_nearest_free_max_m:g} m" if self.cfg.goal_nearest_free else
                 " (goal_nearest_free is off)")
        raise GoalBlockedError(f"the goal ({goal.x:.2f}, {goal.y:.2f}) m is {why}{extra}")
