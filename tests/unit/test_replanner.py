"""The replanner: when to plan (new goal, blocked path, periodic), the jobs, keep-out spots."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from curio.core.clock import SimClock
from curio.core.config import CostmapConfig, PlannerConfig, RecoveryConfig, RobotConfig
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid
from curio.nav.api import GoalHandle, NoPathError, StartBlockedError
from curio.nav.costmap import Costmap
from curio.nav.navigator.replanner import KeepOutSpots, Replanner
from curio.robot import RobotModel

RES = 0.05


def room(obstacle: tuple[float, float] | None = None) -> Costmap:
    """An 8 m room centred on the origin, with a 0.2 m block at ``obstacle``."""
    n = 160
    data = np.zeros((n, n), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    if obstacle is not None:
        r, c = int((obstacle[1] + 4.0) / RES), int((obstacle[0] + 4.0) / RES)
        data[r - 2:r + 2, c - 2:c + 2] = 100
    grid = OccupancyGrid(data, RES, Pose2D(-4.0, -4.0, 0.0))
    return Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())


def straight(x0: float, x1: float, y: float = 0.0) -> npt.NDArray[np.float64]:
    xs = np.arange(x0, x1 + 1e-9, 0.05)
    return np.stack([xs, np.full_like(xs, y), np.zeros_like(xs)], axis=1)


class Follower:
    """The controller as the replanner sees it."""

    def __init__(self, plan: npt.NDArray[np.float64] | None = None, index: int = 0) -> None:
        self.plan = plan if plan is not None else np.zeros((0, 3))
        self.plan_index = index


class FakePlanner:
    """Plans a straight line; raises ``errors`` first, one per call."""

    def __init__(self, *errors: Exception) -> None:
        self.errors = list(errors)
        self.costs: list[npt.NDArray[np.uint8]] = []

    def plan(self, start: Pose2D, goal: Pose2D, costs: npt.NDArray[np.uint8],
             resolution_m: float, origin: Pose2D) -> list[Pose2D]:
        self.costs.append(costs)
        if self.errors:
            raise self.errors.pop(0)
        return [start, goal]


def replanner(costmap: Costmap, planner: FakePlanner | None = None,
              follower: Follower | None = None, **cfg: object) -> Replanner:
    return Replanner(PlannerConfig(**cfg), SimClock(), costmap, planner or FakePlanner(),
                     follower or Follower(), KeepOutSpots(RecoveryConfig(), costmap))


async def test_a_new_goal_is_planned_once_and_its_plan_taken() -> None:
    rp = replanner(room(), replan_rate_hz=0.0)
    handle = GoalHandle(1, [Pose2D(2.0, 0.0, math.nan)])
    assert rp.due(Pose2D(), 0.0, rp.has_plan(0)) == Replanner.NEW_GOAL
    rp.start(Pose2D(), handle, Replanner.NEW_GOAL)
    assert rp.plan_count == 1
    assert rp.due(Pose2D(), 0.1, False) is None  # one job at a time
    poses = rp.take_result(handle)
    assert isinstance(poses, list) and rp.has_plan(0) and not rp.has_plan(1)
    assert poses[-1].yaw == 0.0  # no heading wanted: along the way from the start
    assert rp.due(Pose2D(), 0.2, True) is None


async def test_a_result_for_another_goal_or_waypoint_is_dropped() -> None:
    rp = replanner(room())
    old = GoalHandle(1, [Pose2D(2.0, 0.0), Pose2D(2.0, 2.0)])
    rp.start(Pose2D(), old, "new goal")
    assert rp.take_result(GoalHandle(2, [Pose2D(1.0, 0.0)])) is None
    assert not rp.has_plan(0) and rp.due(Pose2D(), 0.0, False) == Replanner.NEW_GOAL
    rp.start(Pose2D(), old, "new goal")
    old.current_index = 1
    assert rp.take_result(old) is None


async def test_a_planner_error_is_handed_back() -> None:
    rp = replanner(room(), FakePlanner(StartBlockedError("marks under the rover")))
    handle = GoalHandle(1, [Pose2D(2.0, 0.0)])
    rp.start(Pose2D(), handle, "new goal")
    assert isinstance(rp.take_result(handle), StartBlockedError)
    assert not rp.has_plan(0)


async def test_periodic_replans_at_the_rate() -> None:
    rp = replanner(room(), replan_rate_hz=0.5)
    handle = GoalHandle(1, [Pose2D(2.0, 0.0)])
    rp.start(Pose2D(), handle, "new goal")  # at clock 0
    rp.take_result(handle)
    assert rp.due(Pose2D(), 1.9, True) is None
    assert rp.due(Pose2D(), 2.0, True) == Replanner.PERIODIC


async def test_a_blocked_path_is_replanned_after_blocked_confirm_s() -> None:
    cm = room(obstacle=(0.5, 0.0))
    rp = replanner(cm, follower=Follower(straight(-2.0, 3.0)), replan_rate_hz=0.0,
                   blocked_confirm_s=0.5)
    assert rp.blocked(Pose2D(-2.0, 0.0))
    assert rp.due(Pose2D(-2.0, 0.0), 10.0, True) is None  # first seen
    assert rp.due(Pose2D(-2.0, 0.0), 10.375, True) is None
    assert rp.due(Pose2D(-2.0, 0.0), 10.5, True) == Replanner.PATH_BLOCKED


async def test_a_break_in_the_blockage_starts_the_wait_again() -> None:
    follower = Follower(straight(-2.0, 3.0))
    rp = replanner(room(obstacle=(0.5, 0.0)), follower=follower, replan_rate_hz=0.0)
    rp.due(Pose2D(-2.0, 0.0), 10.0, True)
    follower.plan = straight(-2.0, 3.0, y=1.0)  # clear
    assert rp.due(Pose2D(-2.0, 1.0), 10.25, True) is None
    follower.plan = straight(-2.0, 3.0)
    assert rp.due(Pose2D(-2.0, 0.0), 10.375, True) is None  # seen again: from 10.375
    assert rp.due(Pose2D(-2.0, 0.0), 10.75, True) is None
    assert rp.due(Pose2D(-2.0, 0.0), 10.875, True) == Replanner.PATH_BLOCKED


def test_what_counts_as_blocked() -> None:
    rp = replanner(room(obstacle=(0.2, 0.0)), follower=Follower(straight(0.0, 2.0)))
    assert rp.blocked(Pose2D(-0.5, 0.0))
    # The rover's own (inscribed) cells are ignored: leaving a wall is not blocked ...
    cm = room()
    up = straight(-3.82, -1.0)[:, [1, 0, 2]]  # from 0.13 m off the wall at y = -3.95, along y
    assert cm.cost_at(0.0, -3.82) == 253
    assert not replanner(cm, follower=Follower(up)).blocked(Pose2D(0.0, -3.82))
    # ... but only about 3 m (60 poses) ahead of the nearest plan pose count.
    far = replanner(room(obstacle=(1.6, 0.0)), follower=Follower(straight(-2.0, 3.9)))
    assert not far.blocked(Pose2D(-2.0, 0.0))
    off_grid = replanner(room(), follower=Follower(straight(3.0, 5.0)))
    assert off_grid.blocked(Pose2D(3.0, 0.0))
    assert not replanner(room()).blocked(Pose2D())  # no plan


def test_keep_out_spot_half_a_metre_ahead_lethal_until_it_expires() -> None:
    cm = room()
    spots = KeepOutSpots(RecoveryConfig(keep_out_radius_m=0.3, keep_out_s=90.0), cm)
    assert spots.add(Follower(straight(-2.0, 2.0), index=10), Pose2D(-1.5, 0.0), 5.0) \
        == pytest.approx((-1.0, 0.0))
    costs = spots.apply(cm.costs(), Pose2D(-3.0, 1.5), Pose2D(3.0, 0.0), 50.0)
    r, c = cm.world_to_cell(-1.0, 0.0)
    assert costs[r, c] == 254 and cm.costs()[r, c] == 0
    r, c = cm.world_to_cell(-1.0, 0.45)
    assert costs[r, c] == 0  # 0.3 m around the spot only
    assert spots.apply(cm.costs(), Pose2D(-1.0, 0.6), Pose2D(3.0, 0.0), 50.0) is not costs
    assert spots.apply(cm.costs(), Pose2D(-3.0, 1.5), Pose2D(3.0, 0.0), 95.0)[r, c] == 0
    assert spots.spots == []  # expired


def test_keep_out_spots_near_the_start_or_goal_are_left_out() -> None:
    cm = room()
    spots = KeepOutSpots(RecoveryConfig(keep_out_radius_m=0.3), cm)
    spots.spots.append((0.0, 0.0, 1e9))
    plain = cm.costs()
    assert spots.apply(plain, Pose2D(0.69, 0.0), Pose2D(3.0, 0.0), 0.0) is plain
    assert spots.apply(plain, Pose2D(-3.0, 0.0), Pose2D(0.49, 0.0), 0.0) is plain
    assert spots.apply(plain, Pose2D(0.71, 0.0), Pose2D(3.0, 0.0), 0.0) is not plain
    off = KeepOutSpots(RecoveryConfig(keep_out_radius_m=0.0), cm)
    assert off.add(Follower(straight(-2.0, 2.0)), Pose2D(-2.0, 0.0), 0.0) is None


async def test_keep_out_spots_never_cut_the_goal_off() -> None:
    cm = room()
    planner = FakePlanner(NoPathError("cut off by a keep-out spot"))
    rp = replanner(cm, planner)
    rp.keep_out.spots.append((0.0, 0.0, 1e9))
    handle = GoalHandle(1, [Pose2D(2.0, 0.0)])
    rp.start(Pose2D(-2.0, 0.0), handle, "new goal")
    assert isinstance(rp.take_result(handle), list)
    assert planner.costs[0] is not planner.costs[1]  # tried with the spots, then without
    assert planner.costs[1] is cm.costs()


async def test_reset_forgets_the_plan_the_job_and_the_spots() -> None:
    rp = replanner(room())
    handle = GoalHandle(1, [Pose2D(2.0, 0.0)])
    rp.start(Pose2D(), handle, "new goal")
    rp.take_result(handle)
    rp.keep_out.spots.append((0.0, 0.0, 1e9))
    rp.start(Pose2D(), handle, "periodic")
    rp.reset()
    assert not rp.has_plan(0) and rp.keep_out.spots == []
    assert rp.take_result(handle) is None


@pytest.mark.parametrize("yaw", [0.0, 0.3])
def test_cells_of_many_points_are_world_to_cell_of_each(yaw: float) -> None:
    """The blocked check converts the plan ahead in one go: the same cells as the costmap's
    per-point world_to_cell, on an unrotated and a rotated map origin."""
    from curio.nav.navigator.replanner import _cells

    data = np.zeros((120, 90), dtype=np.int8)
    grid = OccupancyGrid(data, RES, Pose2D(-2.1, -1.3, yaw))
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-4.0, 6.0, 3000), rng.uniform(-4.0, 6.0, 3000)
    x[:500] = np.round(x[:500] / RES) * RES  # on cell edges
    rows, cols = _cells(cm, x, y)
    expected = [cm.world_to_cell(float(a), float(b)) for a, b in zip(x, y, strict=True)]
    assert list(zip(rows.tolist(), cols.tolist(), strict=True)) == expected
