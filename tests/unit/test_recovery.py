"""Recovery actions: clear costmap, step back (stopping for what is behind), rotate, wait."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan
from curio.core.topics import CMD_VEL_NAV, EVENTS, SCAN
from curio.estimation.maps import OccupancyGrid
from curio.nav.costmap import Costmap
from curio.nav.recovery import Recovery, points_behind_distance_m
from curio.robot import RobotModel
from tests.unit.test_navigator import FakeRover, room

FOOTPRINT = np.array([(0.33, 0.31), (0.33, -0.31), (-0.33, -0.31), (-0.33, 0.31)])


async def scan_publisher(rover: FakeRover, cfg: Config, world_pts: np.ndarray) -> None:
    """Publish 360-beam scans of fixed world points as seen from the rover's pose."""
    lx, ly, lyaw = cfg.robot.laser_pose
    while True:
        laser = rover.pose @ Pose2D(lx, ly, lyaw)
        local = laser.inverse().transform_points(world_pts) if len(world_pts) else world_pts
        ranges = np.full(360, np.inf, dtype=np.float32)
        for x, y in local:
            i = round((math.atan2(y, x) + math.pi) / (2 * math.pi / 360)) % 360
            ranges[i] = min(ranges[i], math.hypot(x, y))
        rover.bus.publish(SCAN, LaserScan(rover.clock.now(), -math.pi, 2 * math.pi / 360, 0.15,
                                          12.0, ranges))
        await rover.clock.sleep(0.1)


def test_points_behind() -> None:
    pts = np.array([[-0.8, 0.0], [-0.5, 0.5], [1.0, 0.0]])
    assert points_behind_distance_m(pts, FOOTPRINT) == pytest.approx(0.47)
    assert points_behind_distance_m(np.zeros((0, 2)), FOOTPRINT) == math.inf


async def run_step(cfg: Config, step: str, start: Pose2D, world_pts: np.ndarray,
                   grid: OccupancyGrid | None = None) -> tuple[Recovery, FakeRover, object]:
    from curio.core.clock import SimClock
    from curio.core.topics import make_bus

    clock = SimClock()
    bus = make_bus()
    costmap = Costmap(grid or room(), RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    rover = FakeRover(bus, clock, start)
    rec = Recovery(cfg.nav.recovery, RobotModel.from_config(cfg.robot), clock, bus, costmap)
    tasks = [asyncio.create_task(rover.run()),
             asyncio.create_task(scan_publisher(rover, cfg, world_pts))]
    await clock.advance(0.3)
    job = asyncio.create_task(rec.run(step))
    while not job.done():
        await clock.advance(0.1)
    for t in tasks:
        t.cancel()
    return rec, rover, job.result()


async def test_step_back_reverses_the_full_distance_in_open_space(cfg: Config) -> None:
    _rec, rover, outcome = await run_step(cfg, "step_back", Pose2D(1.0, 0.0, 0.0),
                                         np.zeros((0, 2)))
    assert outcome.ok  # type: ignore[attr-defined]
    moved = 1.0 - rover.pose.x
    assert cfg.nav.recovery.step_back_distance_m - 0.03 <= moved <= \
        cfg.nav.recovery.step_back_distance_m + 0.05
    assert min(c.linear_mps for c in rover.commands) == \
        pytest.approx(-cfg.nav.recovery.step_back_speed_mps)
    last = rover.bus.latest(CMD_VEL_NAV)
    assert last is not None and last.linear_mps == 0.0  # it leaves the rover stopped


async def test_step_back_stops_for_an_obstacle_behind(cfg: Config) -> None:
    # A wall 0.9 m behind the rover's rear edge (not on the map: only the scan sees it).
    wall = np.array([[0.0 - 0.33 - 0.9, y] for y in np.arange(-1.0, 1.0, 0.02)])
    _rec, rover, outcome = await run_step(cfg, "step_back", Pose2D(0.0, 0.0, 0.0), wall)
    rear_gap = (rover.pose.x - 0.33) - wall[0, 0]
    assert rear_gap >= cfg.nav.recovery.step_back_clearance_m - 0.05
    assert rear_gap <= cfg.nav.recovery.step_back_clearance_m + 0.1
    assert "behind" in outcome.detail  # type: ignore[attr-defined]


async def test_rotate_where_there_is_room_and_not_where_there_is_none(cfg: Config) -> None:
    _rec, rover, outcome = await run_step(cfg, "rotate", Pose2D(0.0, 0.0, 0.0),
                                         np.zeros((0, 2)))
    assert outcome.ok  # type: ignore[attr-defined]
    assert abs(rover.pose.yaw) == pytest.approx(cfg.nav.recovery.rotate_angle_rad, abs=0.1)
    assert all(c.linear_mps == 0.0 for c in rover.commands)
    # In a corridor just wider than the rover, the corners cannot swing round.
    grid = room()
    res = grid.resolution_m
    r_lo = int((-0.36 - grid.origin.y) / res)
    r_hi = int((0.36 - grid.origin.y) / res)
    grid.data[:r_lo, :] = 100
    grid.data[r_hi:, :] = 100
    _rec2, rover2, outcome2 = await run_step(cfg, "rotate", Pose2D(0.0, 0.0, 0.0),
                                            np.zeros((0, 2)), grid)
    assert not outcome2.ok  # type: ignore[attr-defined]
    assert abs(rover2.pose.yaw) < 0.01


async def test_clear_costmap_forgets_marks_and_wait_waits(cfg: Config) -> None:
    from curio.core.clock import SimClock
    from curio.core.messages import PoseWithCovariance
    from curio.core.topics import POSE, make_bus

    clock = SimClock()
    bus = make_bus()
    grid = room()
    costmap = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    pose = Pose2D(0.0, 0.0, 0.0)
    scan = LaserScan(0.0, -math.pi, 2 * math.pi / 360, 0.15, 12.0,
                     np.where(np.arange(360) == 180, 1.0, np.inf).astype(np.float32))
    costmap.update_from_scan(scan, pose)
    assert costmap.obstacle_mask().any()
    bus.publish(POSE, PoseWithCovariance(0.0, pose))
    events = bus.subscribe(EVENTS)
    rec = Recovery(cfg.nav.recovery, RobotModel.from_config(cfg.robot), clock, bus, costmap)
    outcome = await rec.run("clear_costmap")
    assert outcome.ok and not costmap.obstacle_mask().any()
    job = asyncio.create_task(rec.run("wait"))
    await clock.advance(cfg.nav.recovery.wait_s - 0.5)
    assert not job.done()
    await clock.advance(1.0)
    assert job.done() and job.result().ok
    assert [e.detail["step"] for e in events.drain()] == ["clear_costmap", "wait"]
    with pytest.raises(ValueError, match="allowed"):
        await rec.run("dance")
