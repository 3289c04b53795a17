"""Pinned: the blocked-path detector's thresholds at their shipped values.

Written before the navigation refactor so that it cannot move them by accident. Each test puts
an obstacle (or a stall) just inside and just outside one threshold of ``nav.blocked`` and
asserts the verdict, with every key at its default (the shipped config.toml does not override
``nav.blocked``). The positions are absolute, so changing a default, or removing its check,
breaks a test:

* ``obstacle_distance_m`` = 1.1 m: an obstacle 1.05 m ahead counts, one 1.15 m ahead does not;
* ``obstacle_angle_rad`` = 0.7 rad: 0.5 m away, at a bearing of 0.68 rad it counts, at 0.72 rad
  it does not (both well inside the corridor, so only the cone decides);
* ``no_progress_s`` = 8 s: stalled 7.9 s is not blocked, 8.1 s is;
* ``progress_distance_m`` = 0.1 m: creeping 0.09 m does not restart the timer, 0.11 m does;
* ``corridor_margin_m`` = 0.1 m (+ the footprint's 0.31 m half width): 0.40 m beside the line of
  travel counts, 0.42 m does not;
* the node (5 Hz on a simulated clock and a real bus): BLOCKED turns true between 8.0 and 8.2 s
  after the goal starts, and standing still before the goal does not count.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, Obstacles, Odometry, Path, PoseWithCovariance
from curio.core.topics import BLOCKED, EVENTS, ODOM, PLAN, POSE, SCAN, make_bus
from curio.nav.obstacles import BlockedDetector, ObstacleNode
from curio.robot import RobotModel
from tests.unit.test_obstacles import scan_from

HERE = Pose2D(0.0, 0.0, 0.0)
STALLED_S = 9.0  # longer than no_progress_s: only the geometry decides


def post(x: float, y: float) -> Obstacles:
    """A point-sized obstacle (a circle of radius 0) in ``map``."""
    return Obstacles(0.0, circles=((x, y, 0.0),))


def at_bearing(distance_m: float, bearing_rad: float, travel_yaw: float = 0.0) -> Obstacles:
    """A point obstacle ``distance_m`` from the rover at ``bearing_rad`` off the travel line."""
    a = travel_yaw + bearing_rad
    return post(distance_m * math.cos(a), distance_m * math.sin(a))


def detector(cfg: Config) -> BlockedDetector:
    """A detector whose progress reference is the rover at the origin at t = 0."""
    d = BlockedDetector(cfg.nav.blocked, RobotModel.from_config(cfg.robot))
    d.note_odometry(HERE, 0.0)
    return d


# --- obstacle_distance_m --------------------------------------------------------------------


def test_an_obstacle_just_inside_1_1_m_counts(cfg: Config) -> None:
    d = detector(cfg)
    assert d.in_path(post(1.05, 0.0), HERE, 0.0) == pytest.approx(1.05)
    v = d.evaluate(post(1.05, 0.0), HERE, 0.0, True, STALLED_S)
    assert v.blocked and v.in_path and v.obstacle_distance_m == pytest.approx(1.05)


def test_an_obstacle_just_beyond_1_1_m_does_not_count(cfg: Config) -> None:
    d = detector(cfg)
    assert d.in_path(post(1.15, 0.0), HERE, 0.0) is None
    v = d.evaluate(post(1.15, 0.0), HERE, 0.0, True, STALLED_S)
    assert not v.blocked and not v.in_path and v.reason == "path clear"


def test_the_distance_is_to_a_circles_edge_not_its_centre(cfg: Config) -> None:
    d = detector(cfg)
    # Centre 1.25 m ahead, radius 0.2 m: its edge is 1.05 m away (counts) ...
    assert d.in_path(Obstacles(0.0, circles=((1.25, 0.0, 0.2),)), HERE, 0.0) == \
        pytest.approx(1.05)
    # ... radius 0.1 m: the edge is 1.15 m away (does not).
    assert d.in_path(Obstacles(0.0, circles=((1.25, 0.0, 0.1),)), HERE, 0.0) is None


def test_the_distance_holds_in_any_direction_of_travel(cfg: Config) -> None:
    d = detector(cfg)
    yaw = 2.5  # travelling up and to the left; the rover's own heading is irrelevant
    assert d.in_path(at_bearing(1.05, 0.0, yaw), HERE, yaw) == pytest.approx(1.05)
    assert d.in_path(at_bearing(1.15, 0.0, yaw), HERE, yaw) is None


# --- obstacle_angle_rad ---------------------------------------------------------------------


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_an_obstacle_just_inside_the_0_7_rad_cone_counts(cfg: Config, side: float) -> None:
    d = detector(cfg)
    obs = at_bearing(0.5, side * 0.68)
    assert d.in_path(obs, HERE, 0.0) == pytest.approx(0.5)
    assert d.evaluate(obs, HERE, 0.0, True, STALLED_S).blocked


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_an_obstacle_just_outside_the_0_7_rad_cone_does_not_count(cfg: Config,
                                                                 side: float) -> None:
    d = detector(cfg)
    obs = at_bearing(0.5, side * 0.72)
    # Inside the corridor and within the distance: only the cone keeps it out.
    lateral = abs(0.5 * math.sin(0.72))
    assert lateral < d.half_width_m + cfg.nav.blocked.corridor_margin_m
    assert d.in_path(obs, HERE, 0.0) is None
    assert not d.evaluate(obs, HERE, 0.0, True, STALLED_S).blocked


def test_the_cone_is_centred_on_the_direction_of_travel_not_the_heading(cfg: Config) -> None:
    d = detector(cfg)
    facing = Pose2D(0.0, 0.0, 0.0)  # facing +x, but the plan leads off at 1.2 rad
    assert d.in_path(at_bearing(0.5, 0.68, 1.2), facing, 1.2) == pytest.approx(0.5)
    assert d.in_path(at_bearing(0.5, 0.72, 1.2), facing, 1.2) is None
    assert d.in_path(at_bearing(0.5, -0.72, 1.2), facing, 1.2) is None
    # Without a plan the heading is the direction of travel.
    assert d.evaluate(at_bearing(0.5, 0.68, 1.2), Pose2D(0.0, 0.0, 1.2), None, True,
                      STALLED_S).blocked
    assert not d.evaluate(at_bearing(0.5, 0.72, 1.2), Pose2D(0.0, 0.0, 1.2), None, True,
                          STALLED_S).blocked


# --- corridor_margin_m ----------------------------------------------------------------------


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_the_corridor_is_the_half_width_plus_0_1_m(cfg: Config, side: float) -> None:
    d = detector(cfg)
    assert d.half_width_m == pytest.approx(0.31)  # the footprint this pin assumes
    # 0.8 m ahead, 0.40 / 0.42 m to the side: both within 1.1 m and the 0.7 rad cone.
    assert math.atan2(0.42, 0.8) < 0.7 and math.hypot(0.8, 0.42) < 1.1
    assert d.in_path(post(0.8, side * 0.40), HERE, 0.0) is not None
    assert d.in_path(post(0.8, side * 0.42), HERE, 0.0) is None


# --- no_progress_s and progress_distance_m --------------------------------------------------


def test_blocked_after_8_s_without_progress_not_before(cfg: Config) -> None:
    d = detector(cfg)
    door = post(0.8, 0.0)
    early = d.evaluate(door, HERE, 0.0, True, 7.9)
    assert not early.blocked and early.in_path
    assert early.reason == "obstacle ahead, still moving"
    assert early.stalled_s == pytest.approx(7.9)
    late = d.evaluate(door, HERE, 0.0, True, 8.1)
    assert late.blocked and late.obstacle_distance_m == pytest.approx(0.8)
    assert late.stalled_s == pytest.approx(8.1)


def test_moving_0_11_m_restarts_the_8_s(cfg: Config) -> None:
    d = detector(cfg)
    door = post(0.8, 0.0)
    d.note_odometry(Pose2D(0.11, 0.0, 0.0), 5.0)  # progress at t = 5 s
    assert d.stalled_s(8.1) == pytest.approx(3.1)
    assert not d.evaluate(door, HERE, 0.0, True, 8.1).blocked
    assert not d.evaluate(door, HERE, 0.0, True, 12.9).blocked
    assert d.evaluate(door, HERE, 0.0, True, 13.1).blocked


def test_creeping_0_09_m_is_not_progress(cfg: Config) -> None:
    d = detector(cfg)
    door = post(0.8, 0.0)
    d.note_odometry(Pose2D(0.09, 0.0, 0.0), 5.0)  # less than progress_distance_m
    assert d.stalled_s(8.1) == pytest.approx(8.1)
    assert d.evaluate(door, HERE, 0.0, True, 8.1).blocked


# --- the node on the bus --------------------------------------------------------------------


class DoorScene:
    """An ObstacleNode on a simulated clock and a real bus; the rover stands at the origin
    facing a door across its way (a wall 1 m wide) at ``door_x_m``, publishing pose, odometry,
    a straight plan and a scan every 0.1 s."""

    def __init__(self, cfg: Config, door_x_m: float, goal_active: bool = True) -> None:
        self.cfg = cfg
        self.clock = SimClock()
        self.bus = make_bus()
        self.active = goal_active
        self.node = ObstacleNode(cfg.nav.blocked, RobotModel.from_config(cfg.robot), self.clock,
                                 self.bus,
                                 lambda: self.active)
        self.door = np.array([[door_x_m, y] for y in np.arange(-0.5, 0.5, 0.01)])
        self.events = self.bus.subscribe(EVENTS)
        self.tasks: list[asyncio.Task[None]] = []

    async def world(self) -> None:
        lx, ly, lyaw = self.cfg.robot.laser_pose
        plan = Path(0.0, tuple(Pose2D(0.05 * k, 0.0, 0.0) for k in range(40)))
        while True:
            now = self.clock.now()
            self.bus.publish(POSE, PoseWithCovariance(now, HERE))
            self.bus.publish(ODOM, Odometry(now, HERE))
            self.bus.publish(PLAN, plan)
            s = scan_from(self.door, HERE @ Pose2D(lx, ly, lyaw))
            self.bus.publish(SCAN, LaserScan(now, s.angle_min_rad, s.angle_increment_rad,
                                             0.15, 12.0, s.ranges_m))
            await self.clock.sleep(0.1)

    async def __aenter__(self) -> DoorScene:
        self.tasks = [asyncio.create_task(self.world()), asyncio.create_task(self.node.run())]
        return self

    async def __aexit__(self, *exc: object) -> None:
        for t in self.tasks:
            t.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)

    def blocked(self) -> bool:
        state = self.bus.latest(BLOCKED)
        assert state is not None
        return state.blocked

    def blocked_events(self) -> list[float]:
        return [e.stamp for e in self.events.drain() if e.kind == "nav.blocked"]


async def test_node_reports_blocked_between_8_0_and_8_2_s(cfg: Config) -> None:
    assert cfg.nav.blocked.rate_hz == pytest.approx(5.0)  # one verdict every 0.2 s
    async with DoorScene(cfg, 0.8) as scene:
        await scene.clock.advance(7.9)
        assert not scene.blocked()
        assert scene.blocked_events() == []
        await scene.clock.advance(0.4)
        assert scene.blocked()
        (t_blocked,) = scene.blocked_events()
        assert 8.0 <= t_blocked <= 8.2 + 1e-9


@pytest.mark.parametrize(("door_x_m", "counts"), [(1.05, True), (1.15, False)])
async def test_node_sees_a_door_at_1_05_m_but_not_at_1_15_m(cfg: Config, door_x_m: float,
                                                             counts: bool) -> None:
    async with DoorScene(cfg, door_x_m) as scene:
        await scene.clock.advance(10.0)
        assert scene.blocked() is counts
        state = scene.bus.latest(BLOCKED)
        assert state is not None
        if counts:
            assert state.obstacle_distance_m == pytest.approx(door_x_m, abs=0.02)
        else:
            assert state.obstacle_distance_m is None


async def test_node_counts_the_stall_from_the_start_of_the_goal(cfg: Config) -> None:
    async with DoorScene(cfg, 0.8, goal_active=False) as scene:
        await scene.clock.advance(30.0)  # standing still, no goal: never blocked
        assert not scene.blocked()
        scene.active = True  # a goal starts: the 8 s count from now
        t_goal = scene.clock.now()
        await scene.clock.advance(7.9)
        assert not scene.blocked()
        await scene.clock.advance(0.4)
        assert scene.blocked()
        (t_blocked,) = scene.blocked_events()
        assert 8.0 <= t_blocked - t_goal <= 8.2 + 1e-9
