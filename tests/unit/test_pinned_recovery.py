"""Pinned: the recovery actions' limits at their shipped values (``nav.recovery``).

Written before the navigation refactor so that it cannot move them by accident. Every action
runs on a simulated clock and a real bus against the navigator tests' fake rover (``frozen``:
the wheels spin but the rover does not move, so only a timeout can end an action). Times and
distances are absolute, so changing a default, or removing its check, breaks a test:

* ``step_back_timeout_s`` = 15 s: a rover that cannot reverse stops after 15.0–15.2 s, not
  before 14.9 s;
* ``step_back_distance_m`` = 1.0 m at ``step_back_speed_mps`` = 0.3 m/s;
* ``step_back_clearance_m`` = 0.5 m: something 0.47 m behind the rear edge stops the step back
  before it starts; at 0.53 m the rover reverses, and stops with at most 0.5 m left;
* ``rotate_timeout_s`` = 10 s, ``rotate_angle_rad`` = π/2 (left first);
* ``wait_s`` = 5 s;
* ``clear_radius_m`` = 1.5 m: marks 1.4 m away are forgotten, marks 1.6 m away stay.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, PoseWithCovariance
from curio.core.topics import CMD_VEL_NAV, POSE, make_bus
from curio.nav.costmap import Costmap
from curio.nav.recovery import Recovery, RecoveryOutcome
from curio.robot import RobotModel
from tests.unit.test_navigator import FakeRover, room
from tests.unit.test_recovery import scan_publisher

START = Pose2D(0.0, 0.0, 0.0)


class Scene:
    """A Recovery on a simulated clock and a real bus, with a fake rover and (optionally) a
    scan of fixed world points; ``run`` starts one step and records when it ended."""

    def __init__(self, cfg: Config, *, frozen: bool = False, costmap: bool = True,
                 world_pts: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.clock = SimClock()
        self.bus = make_bus()
        self.rover = FakeRover(self.bus, self.clock, START)
        self.rover.frozen = frozen
        self.costmap = Costmap(room(), RobotModel.from_config(cfg.robot),
                               cfg.nav.costmap) if costmap else None
        self.recovery = Recovery(cfg.nav.recovery, RobotModel.from_config(cfg.robot), self.clock,
                                 self.bus,
                                 self.costmap)
        self.world_pts = world_pts
        self.tasks: list[asyncio.Task[None]] = []
        self.started_s = 0.0
        self.ended_s: float | None = None
        self.job: asyncio.Task[RecoveryOutcome] | None = None

    async def __aenter__(self) -> Scene:
        self.tasks = [asyncio.create_task(self.rover.run())]
        if self.world_pts is not None:
            self.tasks.append(asyncio.create_task(
                scan_publisher(self.rover, self.cfg, self.world_pts)))
        await self.clock.advance(0.3)  # pose, odometry and a scan are on the bus
        return self

    async def __aexit__(self, *exc: object) -> None:
        for t in [*self.tasks, *([self.job] if self.job is not None else [])]:
            t.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        if self.job is not None:
            await asyncio.gather(self.job, return_exceptions=True)

    def run(self, step: str) -> asyncio.Task[RecoveryOutcome]:
        self.started_s = self.clock.now()
        self.job = asyncio.create_task(self.recovery.run(step))
        self.job.add_done_callback(lambda _: setattr(self, "ended_s", self.clock.now()))
        return self.job

    async def finish(self, limit_s: float = 60.0) -> RecoveryOutcome:
        assert self.job is not None
        end = self.clock.now() + limit_s
        while not self.job.done() and self.clock.now() < end:
            await self.clock.advance(0.1)
        assert self.job.done(), f"{self.recovery.running} still running after {limit_s} s"
        return self.job.result()

    @property
    def took_s(self) -> float:
        assert self.ended_s is not None
        return self.ended_s - self.started_s


def wall_behind(cfg: Config, gap_m: float) -> np.ndarray:
    """A wall across the way back, ``gap_m`` behind the footprint's rear edge (rover at START,
    facing +x); only the scan sees it (the map is an empty room)."""
    rear = float(np.asarray(cfg.robot.footprint)[:, 0].min())
    return np.array([[rear - gap_m, y] for y in np.arange(-1.0, 1.0, 0.02)])


# --- step back ------------------------------------------------------------------------------


async def test_step_back_gives_up_after_15_s_not_before(cfg: Config) -> None:
    async with Scene(cfg, frozen=True, costmap=False) as s:
        job = s.run("step_back")
        await s.clock.advance(14.9)
        assert not job.done()  # still reversing (the wheels spin, the rover does not move)
        assert s.rover.commands[-1].linear_mps < 0.0
        await s.clock.advance(0.3)
        assert job.done()
        outcome = job.result()
        assert not outcome.ok and "step-back timeout" in outcome.detail
        assert 15.0 <= s.took_s <= 15.2
        last = s.bus.latest(CMD_VEL_NAV)
        assert last is not None and last.linear_mps == 0.0  # left stopped


async def test_step_back_reverses_1_m_at_0_3_mps(cfg: Config) -> None:
    async with Scene(cfg) as s:
        s.run("step_back")
        outcome = await s.finish()
        assert outcome.ok and "full distance" in outcome.detail
        moved = START.x - s.rover.pose.x
        assert 0.97 <= moved <= 1.05
        assert min(c.linear_mps for c in s.rover.commands) == pytest.approx(-0.3)
        assert 3.3 <= s.took_s <= 5.0  # about 1 m / 0.3 m/s, slowing for the last cm


async def test_step_back_does_not_start_with_0_47_m_behind(cfg: Config) -> None:
    async with Scene(cfg, world_pts=wall_behind(cfg, 0.47)) as s:
        s.run("step_back")
        outcome = await s.finish()
        assert not outcome.ok and "behind" in outcome.detail
        assert all(c.linear_mps == 0.0 for c in s.rover.commands)  # never reversed
        assert s.rover.pose.distance_to(START) < 1e-9


async def test_step_back_with_0_53_m_behind_reverses_to_0_5_m(cfg: Config) -> None:
    wall = wall_behind(cfg, 0.53)
    async with Scene(cfg, world_pts=wall) as s:
        s.run("step_back")
        outcome = await s.finish()
        assert "behind" in outcome.detail
        assert any(c.linear_mps < 0.0 for c in s.rover.commands)  # it did reverse
        rear = float(np.asarray(cfg.robot.footprint)[:, 0].min())
        gap = (s.rover.pose.x + rear) - float(wall[0, 0])
        assert 0.42 <= gap <= 0.5 + 1e-6


# --- rotate ---------------------------------------------------------------------------------


async def test_rotate_gives_up_after_10_s_not_before(cfg: Config) -> None:
    async with Scene(cfg, frozen=True) as s:
        job = s.run("rotate")
        await s.clock.advance(9.9)
        assert not job.done()
        assert s.rover.commands[-1].angular_radps > 0.0
        await s.clock.advance(0.3)
        assert job.done()
        outcome = job.result()
        assert not outcome.ok and "before timeout" in outcome.detail
        assert 10.0 <= s.took_s <= 10.2


async def test_rotate_turns_a_quarter_turn_left(cfg: Config) -> None:
    async with Scene(cfg) as s:
        s.run("rotate")
        outcome = await s.finish()
        assert outcome.ok
        assert s.rover.pose.yaw == pytest.approx(math.pi / 2, abs=0.06)  # left first
        assert max(c.angular_radps for c in s.rover.commands) == pytest.approx(0.6)
        assert all(c.linear_mps == 0.0 for c in s.rover.commands)


# --- wait -----------------------------------------------------------------------------------


async def test_wait_holds_still_for_5_s(cfg: Config) -> None:
    async with Scene(cfg, frozen=True, costmap=False) as s:
        job = s.run("wait")
        await s.clock.advance(4.9)
        assert not job.done()
        await s.clock.advance(0.3)
        assert job.done() and job.result().ok
        assert 5.0 <= s.took_s <= 5.1
        assert all(c.linear_mps == 0.0 and c.angular_radps == 0.0 for c in s.rover.commands)


# --- clear costmap --------------------------------------------------------------------------


async def test_clear_costmap_forgets_marks_within_1_5_m_only(cfg: Config) -> None:
    clock = SimClock()
    bus = make_bus()
    costmap = Costmap(room(), RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    lx, ly, _ = cfg.robot.laser_pose
    # Four returns, 1.4 m (ahead, right) and 1.6 m (left, behind) from the rover's centre.
    beams: dict[int, float] = {  # degrees from straight ahead -> range from the laser
        0: math.sqrt(1.4 ** 2 - ly ** 2) - lx,  # ahead: (lx + r, ly)
        90: math.sqrt(1.6 ** 2 - lx ** 2) - ly,  # left: (lx, ly + r)
        180: math.sqrt(1.6 ** 2 - ly ** 2) + lx,  # behind: (lx - r, ly)
        270: math.sqrt(1.4 ** 2 - lx ** 2) + ly,  # right: (lx, ly - r)
    }
    ranges = np.full(360, np.nan, dtype=np.float32)
    for deg, r in beams.items():
        ranges[(deg + 180) % 360] = r  # beam i looks at -π + i°
    costmap.update_from_scan(LaserScan(0.0, -math.pi, math.radians(1.0), 0.15, 12.0, ranges),
                             START)
    before = np.argwhere(costmap.obstacle_mask())
    assert len(before) == 4
    res, o = costmap.resolution_m, costmap.origin
    dist = {(int(r), int(c)): math.hypot(o.x + (c + 0.5) * res, o.y + (r + 0.5) * res)
            for r, c in before}
    assert sorted(round(d, 1) for d in dist.values()) == [1.4, 1.4, 1.6, 1.6]
    bus.publish(POSE, PoseWithCovariance(0.0, START))
    rec = Recovery(cfg.nav.recovery, RobotModel.from_config(cfg.robot), clock, bus, costmap)
    outcome = await rec.run("clear_costmap")
    assert outcome.ok and "1.5 m" in outcome.detail
    after = costmap.obstacle_mask()
    for (r, c), d in dist.items():
        assert after[r, c] == (d > 1.5), f"mark {d:.2f} m away"
