"""The goal validator: one rule for the navigator's goals and the planner's start and goal."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import PlannerConfig
from curio.core.geometry import Pose2D
from curio.nav.api import (
    GoalBlockedError,
    GoalOutsideMapError,
    InvalidGoalError,
    NavError,
    StartBlockedError,
)
from curio.nav.planner import GlobalPlanner
from curio.nav.validation import GoalValidator, passable_costs

RES = 0.05
ORIGIN = Pose2D()


def centre(r: int, c: int) -> Pose2D:
    return Pose2D((c + 0.5) * RES, (r + 0.5) * RES)


def test_passable_costs() -> None:
    assert passable_costs(False)[:253].all() and not passable_costs(False)[253:].any()
    assert list(passable_costs(True)[253:]) == [False, False, True]


def test_the_navigator_rejects_exactly_the_goals_the_planner_refuses() -> None:
    """Every cell of a grid with walls, inflation and unknown space, for both settings of
    ``allow_unknown``: the navigator's check and the planner agree."""
    rng = np.random.default_rng(3)
    costs = rng.integers(0, 200, (30, 30)).astype(np.uint8)
    costs[10:20, 10:20] = 253
    costs[12:18, 12:18] = 254
    costs[0:6, 22:30] = 255
    costs[25, 3] = 254
    for allow_unknown in (False, True):
        cfg = PlannerConfig(allow_unknown=allow_unknown, goal_nearest_free_max_m=0.2)
        validator, planner = GoalValidator(cfg), GlobalPlanner(cfg)
        for r in range(30):
            for c in range(30):
                goal = centre(r, c)
                try:
                    planner.validator.endpoints(centre(27, 27), goal, costs, RES, ORIGIN)
                    refused = False
                except GoalBlockedError:
                    refused = True
                try:
                    validator.check_goals([goal], costs, RES, ORIGIN)
                    rejected = False
                except GoalBlockedError:
                    rejected = True
                assert rejected == refused, (allow_unknown, r, c, int(costs[r, c]))


def test_a_free_cell_in_the_corner_of_the_square_is_not_near_enough() -> None:
    costs = np.full((21, 21), 254, dtype=np.uint8)
    costs[0, 0] = 0  # 10 cells along both axes from the centre: outside a 10-cell radius
    validator = GoalValidator(PlannerConfig(goal_nearest_free_max_m=10 * RES))
    with pytest.raises(GoalBlockedError, match=r"with no free cell within 0\.5 m"):
        validator.check_goals([centre(10, 10)], costs, RES, ORIGIN)
    costs[0, 10] = 0  # straight down, 10 cells: inside
    validator.check_goals([centre(10, 10)], costs, RES, ORIGIN)


def test_the_navigators_messages_name_the_waypoint_and_the_key() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)
    costs[15:, 15:] = 254
    costs[5, 5] = 253
    validator = GoalValidator(PlannerConfig())
    ok = centre(1, 1)
    with pytest.raises(InvalidGoalError, match="at least one pose"):
        validator.check_goals([], costs, RES, ORIGIN)
    with pytest.raises(InvalidGoalError, match=r"^the goal \(nan, 0.5\) is not a finite"):
        validator.check_goals([Pose2D(math.nan, 0.5)], costs, RES, ORIGIN)
    with pytest.raises(GoalOutsideMapError,
                       match=r"^waypoint 2 of 2 \(3.00, 0.50\) m is outside the map "
                             r"\(x 0.00..2.00 m, y 0.00..2.00 m\)$"):
        validator.check_goals([ok, Pose2D(3.0, 0.5)], costs, RES, ORIGIN)
    with pytest.raises(GoalBlockedError,
                       match=r"^the goal \(1.43, 1.43\) m is inside an obstacle, with no free "
                             r"cell within 0.5 m \(nav.planner.goal_nearest_free_max_m\)$"):
        validator.check_goals([centre(28, 28)], costs, RES, ORIGIN)
    off = GoalValidator(PlannerConfig(goal_nearest_free=False))
    with pytest.raises(GoalBlockedError, match="too close to an obstacle for the rover, with no "
                                               "free cell within 0 m"):
        off.check_goals([centre(5, 5)], costs, RES, ORIGIN)
    validator.check_goals([ok, centre(5, 5), centre(20, 16)], costs, RES, ORIGIN)


def test_the_planners_endpoints() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)
    costs[10, 10] = 253
    costs[20, 20] = 254
    costs[30:, 30:] = 254
    validator = GoalValidator(PlannerConfig(goal_nearest_free_max_m=0.2))
    ends = validator.endpoints(centre(10, 10), centre(38, 31), costs, RES, ORIGIN)
    assert ends.start_cell == (10, 10) and ends.start_cost == 253  # may drive out
    assert ends.start_xy == pytest.approx((10.5 * RES, 10.5 * RES))
    assert ends.goal_moved and ends.goal_cell == (38, 29)
    assert (ends.goal.x, ends.goal.y) == pytest.approx(ends.goal_xy)
    with pytest.raises(StartBlockedError, match="is in an obstacle"):
        validator.endpoints(centre(20, 20), centre(1, 1), costs, RES, ORIGIN)
    costs[5, 5] = 255
    with pytest.raises(StartBlockedError, match="is in unknown space"):
        validator.endpoints(centre(5, 5), centre(1, 1), costs, RES, ORIGIN)
    GoalValidator(PlannerConfig(allow_unknown=True)).endpoints(centre(5, 5), centre(1, 1), costs,
                                                               RES, ORIGIN)
    with pytest.raises(GoalBlockedError, match="no free cell lies within"):
        validator.endpoints(centre(1, 1), centre(36, 36), costs, RES, ORIGIN)
    with pytest.raises(NavError, match="not a finite position; x and y"):
        validator.endpoints(centre(1, 1), Pose2D(math.inf, 0.0), costs, RES, ORIGIN)
