"""The navigator: goal lifecycle, bad goals, preemption, cancel, waypoints, replans, recovery."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import EStop, Odometry, OperatorCommand, PoseWithCovariance, Twist
from curio.core.topics import CMD_VEL_NAV, ESTOP, EVENTS, ODOM, OPERATOR, PLAN, POSE, make_bus
from curio.estimation.maps import OccupancyGrid
from curio.nav.api import (
    GoalBlockedError,
    GoalOutsideMapError,
    GoalState,
    NoPathError,
)
from curio.nav.controller import LocalController
from curio.nav.costmap import Costmap
from curio.nav.navigator import InvalidGoalError, NavigatorNode
from curio.nav.planner import GlobalPlanner
from curio.nav.recovery import Recovery
from curio.robot import RobotModel


def room(size_m: float = 8.0, res: float = 0.05) -> OccupancyGrid:
    """A walled room centred on the origin."""
    n = int(size_m / res)
    data = np.zeros((n, n), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return OccupancyGrid(data, res, Pose2D(-size_m / 2, -size_m / 2, 0.0))


def cell(grid: OccupancyGrid, x: float, y: float) -> tuple[int, int]:
    return (int((y - grid.origin.y) / grid.resolution_m),
            int((x - grid.origin.x) / grid.resolution_m))


class FakeRover:
    """Integrates unicycle kinematics from ``/cmd_vel_nav`` and publishes ``/pose`` and
    ``/odom`` (a perfect estimate) at 20 Hz. ``frozen`` makes the wheels spin in place."""

    def __init__(self, bus: Bus, clock: SimClock, pose: Pose2D) -> None:
        self.bus = bus
        self.clock = clock
        self.pose = pose
        self.frozen = False
        self.commands: list[Twist] = []

    async def run(self) -> None:
        sub = self.bus.subscribe(CMD_VEL_NAV)
        dt = 0.05
        cmd = Twist(0.0)
        while True:
            for c in sub.drain():
                cmd = c
                self.commands.append(c)
            now = self.clock.now()
            if now - cmd.stamp > 0.5:
                cmd = Twist(now)
            v, w = (0.0, 0.0) if self.frozen else (cmd.linear_mps, cmd.angular_radps)
            p = self.pose
            th = p.yaw + 0.5 * w * dt
            self.pose = Pose2D(p.x + v * dt * math.cos(th), p.y + v * dt * math.sin(th),
                               wrap_angle(p.yaw + w * dt))
            self.bus.publish(POSE, PoseWithCovariance(now, self.pose))
            self.bus.publish(ODOM, Odometry(now, self.pose, v, w))
            await self.clock.sleep(dt)


class Harness:
    """A navigator on a small map with a fake rover, on a simulated clock."""

    def __init__(self, cfg: Config, grid: OccupancyGrid, start: Pose2D,
                 with_recovery: bool = True) -> None:
        self.cfg = cfg
        self.clock = SimClock()
        self.bus = make_bus()
        self.costmap = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
        self.planner = GlobalPlanner(cfg.nav.planner)
        self.controller = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot),
                                          self.costmap)
        self.recovery = Recovery(cfg.nav.recovery, RobotModel.from_config(cfg.robot), self.clock,
                                 self.bus,
                                 self.costmap) if with_recovery else None
        self.nav = NavigatorNode(cfg, self.clock, self.bus, self.costmap, self.planner,
                                 self.controller, self.recovery)
        self.rover = FakeRover(self.bus, self.clock, start)
        self.events = self.bus.subscribe(EVENTS)
        self.tasks: list[asyncio.Task[None]] = []

    async def __aenter__(self) -> Harness:
        self.tasks = [asyncio.create_task(self.rover.run()), asyncio.create_task(self.nav.run())]
        await self.clock.advance(0.1)
        return self

    async def __aexit__(self, *exc: object) -> None:
        for t in self.tasks:
            t.cancel()
        for t in self.tasks:
            with pytest.raises(asyncio.CancelledError):
                await t

    async def until(self, pred: object, timeout_s: float) -> bool:
        end = self.clock.now() + timeout_s
        while self.clock.now() < end:
            if pred():  # type: ignore[operator]
                return True
            await self.clock.advance(0.1)
        return bool(pred())  # type: ignore[operator]

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events.drain()]


@pytest.fixture
def fast_cfg(cfg: Config) -> Config:
    rec = cfg.nav.recovery.model_copy(update={"wait_s": 1.0, "max_rounds": 1})
    nav = cfg.nav.model_copy(update={"recovery": rec})
    return cfg.model_copy(update={"nav": nav})


async def test_goal_succeeds_with_events_plan_and_feedback(fast_cfg: Config) -> None:
    async with Harness(fast_cfg, room(), Pose2D(-2.0, -2.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.0, 1.5, math.nan), tag="t1")
        assert handle.state is GoalState.PENDING
        await h.clock.advance(0.3)
        assert handle.state is GoalState.ACTIVE
        await h.clock.advance(2.0)
        plan = h.bus.latest(PLAN)
        assert plan is not None and len(plan.poses) > 10
        first_remaining = handle.distance_remaining_m
        assert first_remaining is not None and first_remaining > 4.0
        assert handle.eta_s is not None and handle.eta_s > 0
        assert await h.until(lambda: handle.done, 90.0)
        assert handle.state is GoalState.SUCCEEDED, handle.history
        assert h.rover.pose.distance_to(Pose2D(2.0, 1.5)) <= \
            fast_cfg.nav.controller.xy_goal_tolerance_m + 0.01
        kinds = h.kinds()
        assert kinds.index("nav.goal_accepted") < kinds.index("nav.goal_succeeded")
        assert any(c.linear_mps > 0.2 for c in h.rover.commands)
        assert h.nav.active is None


@pytest.mark.parametrize(
    ("goal", "error"),
    [
        (Pose2D(50.0, 0.0), GoalOutsideMapError),
        (Pose2D(math.nan, 0.0), InvalidGoalError),
        (Pose2D(0.0, 0.0), GoalBlockedError),  # in the middle of a 2 m block
    ],
)
async def test_bad_goals_are_rejected_at_once(fast_cfg: Config, goal: Pose2D,
                                              error: type[Exception]) -> None:
    grid = room()
    r, c = cell(grid, -1.0, -1.0)
    grid.data[r:r + 40, c:c + 40] = 100
    async with Harness(fast_cfg, grid, Pose2D(-3.0, -3.0, 0.0)) as h:
        handle = h.nav.send_goal(goal)
        assert handle.state is GoalState.REJECTED
        assert isinstance(handle.error, error)
        assert str(handle.error)  # a sentence for the operator
        assert "nav.goal_rejected" in h.kinds()
        assert h.nav.active is None
    empty = h.nav.send_goal([])
    assert empty.state is GoalState.REJECTED


async def test_goal_next_to_a_wall_moves_to_nearest_free(fast_cfg: Config) -> None:
    async with Harness(fast_cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(3.85, 0.0, math.nan))  # 10 cm from the wall
        assert handle.state is GoalState.PENDING
        assert await h.until(lambda: handle.done, 60.0)
        # Reached the nearest free spot; the goal itself is not reachable by the footprint.
        assert handle.state in (GoalState.SUCCEEDED, GoalState.ABORTED)
        assert h.rover.pose.x > 2.8


async def test_preempt_and_cancel(fast_cfg: Config) -> None:
    async with Harness(fast_cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        a = h.nav.send_goal(Pose2D(2.0, 0.0, math.nan), tag="a")
        await h.clock.advance(3.0)
        b = h.nav.send_goal(Pose2D(-2.0, 2.0, math.nan), tag="b")
        assert a.state is GoalState.PREEMPTED
        assert h.nav.active is b
        await h.clock.advance(3.0)
        assert b.state is GoalState.ACTIVE
        h.nav.cancel()
        assert b.state is GoalState.PREEMPTED
        assert h.nav.active is None
        kinds = h.kinds()
        assert "nav.goal_preempted" in kinds and "nav.goal_canceled" in kinds
        await h.clock.advance(0.5)
        assert h.rover.commands[-1].linear_mps == 0.0
        assert h.rover.commands[-1].angular_radps == 0.0


async def test_operator_goto_and_cancel_and_estop(fast_cfg: Config) -> None:
    async with Harness(fast_cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        h.bus.publish(OPERATOR, OperatorCommand(h.clock.now(), "goto", goal=Pose2D(1.0, 0.0),
                                                source="web"))
        await h.clock.advance(0.5)
        handle = h.nav.active
        assert handle is not None and handle.poses[0] == Pose2D(1.0, 0.0)
        h.bus.publish(OPERATOR, OperatorCommand(h.clock.now(), "cancel", source="web"))
        await h.clock.advance(0.5)
        assert handle.state is GoalState.PREEMPTED and h.nav.active is None
        h.bus.publish(OPERATOR, OperatorCommand(h.clock.now(), "goto", goal=Pose2D(1.0, 0.0),
                                                source="web"))
        await h.clock.advance(1.0)
        second = h.nav.active
        assert second is not None
        h.bus.publish(ESTOP, EStop(h.clock.now(), True, source="web"))
        await h.clock.advance(0.5)
        assert second.state is GoalState.PREEMPTED


async def test_waypoint_sequence(fast_cfg: Config) -> None:
    async with Harness(fast_cfg, room(), Pose2D(-2.0, -2.0, 0.0)) as h:
        wps = [Pose2D(0.0, -2.0, math.nan), Pose2D(0.0, 0.0, math.nan),
               Pose2D(-1.5, 1.0, math.pi)]
        handle = h.nav.send_goal(wps, tag="seq")
        assert await h.until(lambda: handle.done, 120.0)
        assert handle.state is GoalState.SUCCEEDED, handle.history
        assert handle.current_index == 2
        assert h.kinds().count("nav.waypoint_reached") == 2
        assert abs(wrap_angle(h.rover.pose.yaw - math.pi)) <= \
            fast_cfg.nav.controller.yaw_goal_tolerance_rad + 0.02


async def test_unreachable_goal_climbs_the_ladder_then_aborts(fast_cfg: Config) -> None:
    grid = room()
    # A closed box around (2, 2): the goal inside is free but cut off.
    r, c = cell(grid, 1.0, 1.0)
    grid.data[r:r + 41, c] = grid.data[r:r + 41, c + 40] = 100
    grid.data[r, c:c + 41] = grid.data[r + 40, c:c + 41] = 100
    async with Harness(fast_cfg, grid, Pose2D(-2.0, -2.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.0, 2.0, math.nan))
        assert await h.until(lambda: handle.done, 120.0)
        assert handle.state is GoalState.ABORTED
        assert isinstance(handle.error, NoPathError)
        assert "after recovery" in str(handle.error)
        steps = [rec.name for rec in h.recovery.history]  # type: ignore[union-attr]
        assert steps == list(fast_cfg.nav.recovery.ladder)
        ev = h.events.drain()
        aborted = [e for e in ev if e.kind == "nav.goal_aborted"]
        assert aborted and aborted[0].detail["code"] == "no_path"


async def test_replans_at_once_when_the_path_is_blocked(fast_cfg: Config) -> None:
    cfg = fast_cfg.model_copy(deep=True)
    cfg.nav.planner.replan_rate_hz = 0.0  # only when needed
    grid = room()
    async with Harness(cfg, grid, Pose2D(-3.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(3.0, 0.0, math.nan))
        await h.clock.advance(1.0)
        plans = h.nav.plan_count
        first = h.bus.latest(PLAN)
        assert first is not None and max(abs(p.y) for p in first.poses) < 0.1
        # Something appears on the straight line (as the obstacle layer would mark it).
        blocked = grid.data.copy()
        r, c = cell(grid, -1.0, -0.5)  # about 2 m ahead
        blocked[r:r + 20, c:c + 10] = 100
        h.costmap.set_static_map(OccupancyGrid(blocked, grid.resolution_m, grid.origin))
        await h.clock.advance(0.3)  # not yet: a blockage must last blocked_confirm_s (0.5 s)
        assert h.nav.plan_count == plans
        await h.clock.advance(0.5)
        assert h.nav.plan_count > plans
        assert "nav.path_blocked" in h.kinds()
        new = h.bus.latest(PLAN)
        assert new is not None and max(abs(p.y) for p in new.poses) > 0.6
        assert await h.until(lambda: handle.done, 60.0)
        assert handle.state is GoalState.SUCCEEDED


async def test_a_blockage_shorter_than_the_confirm_time_keeps_the_plan(
        fast_cfg: Config) -> None:
    """A cell that flickers onto the path for one scan (lidar noise) does not swap the plan."""
    cfg = fast_cfg.model_copy(deep=True)
    cfg.nav.planner.replan_rate_hz = 0.0  # only when needed
    grid = room()
    async with Harness(cfg, grid, Pose2D(-3.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(3.0, 0.0, math.nan))
        await h.clock.advance(1.0)
        plans = h.nav.plan_count
        blocked = grid.data.copy()
        r, c = cell(grid, -1.0, 0.0)  # about 1.8 m ahead
        blocked[r, c] = 100
        for _ in range(3):  # on for 0.2 s, off for 0.2 s
            h.costmap.set_static_map(OccupancyGrid(blocked, grid.resolution_m, grid.origin))
            await h.clock.advance(0.2)
            h.costmap.set_static_map(OccupancyGrid(grid.data.copy(), grid.resolution_m,
                                                   grid.origin))
            await h.clock.advance(0.2)
        assert h.nav.plan_count == plans
        assert "nav.path_blocked" not in h.kinds()
        assert await h.until(lambda: handle.done, 60.0)
        assert handle.state is GoalState.SUCCEEDED


async def test_no_progress_triggers_recovery(fast_cfg: Config) -> None:
    cfg = fast_cfg.model_copy(deep=True)
    cfg.nav.controller.progress_timeout_s = 3.0
    cfg.nav.recovery.ladder = ["wait"]
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        h.rover.frozen = True
        handle = h.nav.send_goal(Pose2D(2.0, 0.0, math.nan))
        assert await h.until(lambda: handle.done, 60.0)
        assert handle.state is GoalState.ABORTED
        assert handle.error is not None and handle.error.code == "no_progress"
        assert handle.recoveries == 1




async def test_no_progress_towards_the_goal_makes_a_keep_out_spot(fast_cfg: Config) -> None:
    cfg = fast_cfg.model_copy(deep=True)
    cfg.nav.controller.progress_timeout_s = 1000.0  # only the goal-progress check can fire
    cfg.nav.recovery.goal_progress_timeout_s = 5.0
    cfg.nav.recovery.ladder = ["wait"]
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        h.rover.frozen = True  # the wheels turn, the rover gets no closer
        handle = h.nav.send_goal(Pose2D(2.0, 0.0, math.nan))
        assert await h.until(lambda: handle.done, 60.0)
        assert handle.state is GoalState.ABORTED
        assert handle.error is not None and handle.error.code == "no_progress"
        kinds = h.kinds()
        assert "nav.keep_out" in kinds
        # The spot ahead of the rover is lethal for the next plans (start and goal exempt).
        x, y, _ = h.nav.keep_out[0]
        assert -1.8 < x < -1.2 and abs(y) < 0.1
        costs = h.nav._with_keep_out(h.costmap.costs(), Pose2D(-3.0, 1.5), Pose2D(3.0, 0.0))
        r, c = h.costmap.world_to_cell(x, y)
        assert costs[r, c] == 254 and h.costmap.costs()[r, c] < 253


async def test_holds_while_localisation_is_lost_then_goes_on(fast_cfg: Config) -> None:
    from curio.core.messages import LocalizationStatus
    from curio.core.topics import LOCALIZATION

    cfg = fast_cfg.model_copy(deep=True)
    cfg.nav.controller.lost_timeout_s = 20.0
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.5, 0.0, math.nan))
        await h.clock.advance(3.0)
        assert handle.state is GoalState.ACTIVE
        h.bus.publish(LOCALIZATION, LocalizationStatus(h.clock.now(), "lost"))
        await h.clock.advance(1.0)  # brake
        held_at = h.rover.pose
        n_cmds = len(h.rover.commands)
        await h.clock.advance(15.0)  # less than the timeout: held, goal still active
        assert handle.state is GoalState.ACTIVE
        assert h.rover.pose.distance_to(held_at) < 0.02
        assert all(c.linear_mps == 0.0 and c.angular_radps == 0.0
                   for c in h.rover.commands[n_cmds:])
        assert "nav.holding" in h.kinds()
        h.bus.publish(LOCALIZATION, LocalizationStatus(h.clock.now(), "ok"))
        assert await h.until(lambda: handle.done, 60.0)
        assert handle.state is GoalState.SUCCEEDED, handle.history
        assert handle.recoveries == 0  # holding is not being stuck


async def test_aborts_when_still_lost_after_the_timeout(fast_cfg: Config) -> None:
    from curio.core.messages import LocalizationStatus
    from curio.core.topics import LOCALIZATION
    from curio.nav.api import LocalizationLostError

    cfg = fast_cfg.model_copy(deep=True)
    cfg.nav.controller.lost_timeout_s = 4.0
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.5, 0.0, math.nan))
        await h.clock.advance(2.0)
        h.bus.publish(LOCALIZATION, LocalizationStatus(h.clock.now(), "lost"))
        t_lost = h.clock.now()
        assert await h.until(lambda: handle.done, 20.0)
        assert handle.state is GoalState.ABORTED
        assert isinstance(handle.error, LocalizationLostError)
        assert "lost_timeout_s" in str(handle.error)
        assert 4.0 <= h.clock.now() - t_lost <= 5.0


async def test_keep_out_spots_never_cut_the_goal_off(fast_cfg: Config) -> None:
    """A keep-out spot in the only door: the plan goes through the door anyway."""
    grid = room()
    _, c = cell(grid, 0.0, 0.0)
    grid.data[:, c:c + 2] = 100  # a wall across x = 0 ...
    rd, _ = cell(grid, 0.0, 1.0)
    grid.data[rd - 10:rd + 10, c:c + 2] = 0  # ... with a 1 m door at y = 1
    async with Harness(fast_cfg, grid, Pose2D(-2.0, 1.0, 0.0)) as h:
        h.nav.keep_out.append((0.0, 1.0, 1e9))
        costs = h.nav._with_keep_out(h.costmap.costs(), Pose2D(-2.0, 1.0), Pose2D(2.0, 1.0))
        with pytest.raises(NoPathError):
            h.planner.plan(Pose2D(-2.0, 1.0), Pose2D(2.0, 1.0, 0.0), costs,
                           h.costmap.resolution_m, h.costmap.origin)
        handle = h.nav.send_goal(Pose2D(2.0, 1.0, math.nan))
        await h.clock.advance(0.3)
        assert handle.state is GoalState.ACTIVE
        h.nav.keep_out.append((0.0, 1.0, 1e9))  # activation forgot the old ones
        assert await h.until(lambda: handle.done, 90.0)
        assert handle.state is GoalState.SUCCEEDED, handle.history
        assert h.nav.plan_count > 2  # replanned with the spot in place ...
        assert handle.recoveries == 0  # ... and never found itself cut off
