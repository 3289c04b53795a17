"""Obstacle extraction and the blocked detector, including the original's defects 19–25."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, Obstacles, Odometry, Path, PoseWithCovariance
from curio.core.topics import BLOCKED, EVENTS, OBSTACLES, ODOM, PLAN, POSE, SCAN, make_bus
from curio.nav.obstacles import (
    BlockedDetector,
    ObstacleExtractor,
    ObstacleNode,
    obstacle_points,
    travel_direction,
)
from curio.robot import RobotModel


def scan_from(world_pts: np.ndarray, laser: Pose2D, beams: int = 720) -> LaserScan:
    local = laser.inverse().transform_points(world_pts)
    ranges = np.full(beams, np.inf, dtype=np.float32)
    inc = 2 * math.pi / beams
    for x, y in local:
        i = round((math.atan2(y, x) + math.pi) / inc) % beams
        ranges[i] = min(ranges[i], math.hypot(x, y))
    return LaserScan(0.0, -math.pi, inc, 0.15, 12.0, ranges)


def test_extracts_a_wall_as_a_segment_and_a_post_as_a_circle(cfg: Config) -> None:
    wall = np.array([[2.0, y] for y in np.arange(-1.0, 1.0, 0.005)])
    ang = np.linspace(0, 2 * math.pi, 400)
    post = np.stack([-1.5 + 0.1 * np.cos(ang), 0.5 + 0.1 * np.sin(ang)], axis=1)
    ex = ObstacleExtractor(cfg.nav.blocked, Pose2D(0.0, 0.0, 0.0))
    robot = Pose2D(0.5, 0.2, 0.3)
    obs = ex.extract(scan_from(np.vstack([wall, post]), robot), robot)
    assert obs.frame_id == "map"
    long_segs = [s for s in obs.segments if math.dist(*s) > 1.0]
    assert len(long_segs) >= 1
    (x1, _y1), (x2, _y2) = long_segs[0]
    assert x1 == pytest.approx(2.0, abs=0.03) and x2 == pytest.approx(2.0, abs=0.03)
    near_post = [c for c in obs.circles if math.hypot(c[0] + 1.5, c[1] - 0.5) < 0.15]
    assert len(near_post) == 1
    assert 0.05 < near_post[0][2] < 0.3


def test_a_wall_across_the_scans_seam_is_one_segment(cfg: Config) -> None:
    """The scan starts and ends behind the rover (−π/+π): a wall there is one obstacle, not
    two halves split at the seam."""
    wall = np.array([[-2.0, y] for y in np.arange(-1.0, 1.0, 0.005)])
    ex = ObstacleExtractor(cfg.nav.blocked, Pose2D(0.0, 0.0, 0.0))
    robot = Pose2D(0.0, 0.0, 0.0)
    obs = ex.extract(scan_from(wall, robot), robot)
    assert obs.circles == ()
    assert len(obs.segments) == 1
    (x1, y1), (x2, y2) = obs.segments[0]
    assert x1 == pytest.approx(-2.0, abs=0.02) and x2 == pytest.approx(-2.0, abs=0.02)
    assert abs(y2 - y1) > 1.9


def test_no_valid_beam_gives_no_obstacles(cfg: Config) -> None:
    ex = ObstacleExtractor(cfg.nav.blocked, Pose2D(0.0, 0.0, 0.0))
    ranges = np.full(360, np.nan, dtype=np.float32)
    ranges[::7] = np.inf
    obs = ex.extract(LaserScan(0.0, -math.pi, 2 * math.pi / 360, 0.15, 12.0, ranges), Pose2D())
    assert obs.segments == () and obs.circles == ()


def test_travel_direction_from_the_plan() -> None:
    plan = [Pose2D(0.0, y * 0.05, 0.0) for y in range(40)]
    assert travel_direction(plan, Pose2D(0.0, 0.0, 0.0)) == pytest.approx(math.pi / 2)
    assert travel_direction(plan[:1], Pose2D()) is None  # a 1-pose plan does not crash (22)


def _det(cfg: Config) -> BlockedDetector:
    d = BlockedDetector(cfg.nav.blocked, RobotModel.from_config(cfg.robot))
    d.note_odometry(Pose2D(0.0, 0.0, 0.0), 0.0)  # a rover exactly at (0, 0) counts (21)
    return d


def test_blocked_needs_an_obstacle_ahead_and_no_progress(cfg: Config) -> None:
    d = _det(cfg)
    wall = Obstacles(0.0, segments=(((1.0, -1.0), (1.0, 1.0)),))
    here = Pose2D(0.0, 0.0, 0.0)
    assert not d.evaluate(wall, here, 0.0, True, 5.0).blocked  # not stalled long enough
    v = d.evaluate(wall, here, 0.0, True, 8.5)
    assert v.blocked and v.obstacle_distance_m == pytest.approx(1.0, abs=0.01)
    # Nothing in the cone: not blocked however long it stands.
    behind = Obstacles(0.0, segments=(((-1.0, -1.0), (-1.0, 1.0)),))
    assert not d.evaluate(behind, here, 0.0, True, 30.0).blocked
    far = Obstacles(0.0, segments=(((1.5, -1.0), (1.5, 1.0)),))
    assert not d.evaluate(far, here, 0.0, True, 30.0).blocked  # beyond 1.1 m


def test_progress_is_measured_on_odometry(cfg: Config) -> None:
    d = _det(cfg)
    wall = Obstacles(0.0, segments=(((1.0, -1.0), (1.0, 1.0)),))
    for k in range(1, 20):  # creeping forward 0.06 m/s: progress every 2 s
        d.note_odometry(Pose2D(0.06 * k, 0.0, 0.0), float(k))
        assert not d.evaluate(wall, Pose2D(), 0.0, True, float(k)).blocked
    assert d.stalled_s(19.5) < 2.5


def test_circles_count(cfg: Config) -> None:  # defect 20
    d = _det(cfg)
    post = Obstacles(0.0, circles=((0.8, 0.1, 0.15),))
    assert d.evaluate(post, Pose2D(), 0.0, True, 9.0).blocked


def test_bearings_are_wrapped(cfg: Config) -> None:  # defect 19
    d = _det(cfg)
    # Travelling towards −x (yaw ≈ π) with the obstacle just across the ±π seam.
    post = Obstacles(0.0, circles=((-0.9, -0.1, 0.1),))
    assert d.evaluate(post, Pose2D(0.0, 0.0, math.pi - 0.05), math.pi - 0.05, True,
                      9.0).blocked


def test_never_blocked_without_an_active_goal(cfg: Config) -> None:  # defect 24
    d = _det(cfg)
    wall = Obstacles(0.0, segments=(((0.6, -1.0), (0.6, 1.0)),))
    v = d.evaluate(wall, Pose2D(), 0.0, False, 100.0)
    assert not v.blocked and v.reason == "no active goal"


def test_walls_beside_a_narrow_corridor_never_block(cfg: Config) -> None:  # defect 25
    d = _det(cfg)
    corridor = Obstacles(0.0, segments=(((-2.0, 0.45), (3.0, 0.45)),
                                        ((-2.0, -0.45), (3.0, -0.45))))
    v = d.evaluate(corridor, Pose2D(), 0.0, True, 100.0)
    assert not v.blocked and not v.in_path
    # ... but a door closed across it does.
    closed = Obstacles(0.0, segments=(*corridor.segments, ((0.9, -0.45), (0.9, 0.45))))
    assert d.evaluate(closed, Pose2D(), 0.0, True, 100.0).blocked


async def test_node_publishes_obstacles_blocked_and_events(cfg: Config) -> None:
    clock = SimClock()
    bus = make_bus()
    active = {"goal": True}
    node = ObstacleNode(cfg.nav.blocked, RobotModel.from_config(cfg.robot), clock, bus,
                        lambda: active["goal"])
    events = bus.subscribe(EVENTS)
    pose = Pose2D(0.0, 0.0, 0.0)
    lx, ly, lyaw = cfg.robot.laser_pose
    door = np.array([[0.9, y] for y in np.arange(-0.6, 0.6, 0.01)])
    task = asyncio.create_task(node.run())
    for _ in range(100):  # 10 s standing in front of a closed door
        bus.publish(POSE, PoseWithCovariance(clock.now(), pose))
        bus.publish(ODOM, Odometry(clock.now(), pose))
        bus.publish(PLAN, Path(clock.now(), tuple(Pose2D(0.05 * k, 0, 0) for k in range(40))))
        s = scan_from(door, pose @ Pose2D(lx, ly, lyaw))
        bus.publish(SCAN, LaserScan(clock.now(), s.angle_min_rad, s.angle_increment_rad,
                                    0.15, 12.0, s.ranges_m))
        await clock.advance(0.1)
    state = bus.latest(BLOCKED)
    assert state is not None and state.blocked
    assert bus.latest(OBSTACLES) is not None
    active["goal"] = False  # the goal is cancelled: not blocked any more
    await clock.advance(0.5)
    assert not bus.latest(BLOCKED).blocked  # type: ignore[union-attr]
    kinds = [e.kind for e in events.drain()]
    assert "nav.blocked" in kinds and kinds[-1] == "nav.unblocked"
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


def _points_one_by_one(obs: Obstacles, step_m: float = 0.05) -> np.ndarray:
    """obstacle_points before it sampled every segment in one pass (verbatim)."""
    rows = []
    for (x1, y1), (x2, y2) in obs.segments:
        n = max(2, int(math.hypot(x2 - x1, y2 - y1) / step_m) + 1)
        t = np.linspace(0.0, 1.0, n)
        rows.append(np.stack([x1 + t * (x2 - x1), y1 + t * (y2 - y1), np.zeros(n)], axis=1))
    if obs.circles:
        rows.append(np.asarray(obs.circles, dtype=np.float64).reshape(-1, 3))
    if not rows:
        return np.zeros((0, 3))
    return np.vstack(rows)


def test_obstacle_points_are_the_per_segment_samples() -> None:
    rng = np.random.default_rng(4)
    for k in range(50):
        segs = tuple(((float(a), float(b)), (float(c), float(d)))
                     for a, b, c, d in rng.uniform(-6, 6, (k % 7, 4)))
        circles = tuple((float(x), float(y), float(r)) for x, y, r in rng.uniform(0, 1, (k % 3, 3)))
        obs = Obstacles(0.0, segs, circles)
        assert np.array_equal(obstacle_points(obs), _points_one_by_one(obs))
