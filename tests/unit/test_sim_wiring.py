"""Simulator wiring: SimBase (cmd_vel → servos, timeout, halt) and the sensor publishers."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Twist
from curio.core.topics import (
    BATTERY,
    CMD_VEL,
    EVENTS,
    GROUND_TRUTH,
    HEALTH,
    IMU,
    SCAN,
    SERVO_CMD,
    WHEEL_ODOM,
    WHEELS,
    make_bus,
)
from curio.drivers.kinematics import twist_to_servo_command
from curio.drivers.odometry import WheelOdometry
from curio.robot import RobotModel
from curio.sim.base import SimBase
from curio.sim.wiring import Simulator
from curio.sim.world import World
from tests.unit.test_sim_raycast import room


async def run_parts(clock: SimClock, parts: list[Callable[[], Awaitable[None]]],
                    until_s: float) -> None:
    tasks = [asyncio.create_task(p()) for p in parts]
    await clock.run(until_s=until_s)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


def make(cfg: Config | None = None) -> tuple[Config, Any, SimClock, World, Simulator, SimBase]:
    cfg = cfg or Config()
    bus = make_bus()
    clock = SimClock()
    world = World(room(), cfg, Pose2D(1.0, 2.0, 0.0))
    return cfg, bus, clock, world, Simulator(cfg, bus, clock, world, True), SimBase(
        cfg, bus, clock, world, RobotModel.from_config(cfg.robot))


async def test_sensor_rates_and_frames() -> None:
    _cfg, bus, clock, _world, sim, _base = make()
    subs = {t.name: bus.subscribe(t, maxsize=1000) for t in (SCAN, IMU, WHEELS, BATTERY,
                                                             GROUND_TRUTH)}
    await run_parts(clock, [sim.run_physics, sim.run_scan, sim.run_imu, sim.run_wheels,
                            sim.run_battery], 2.0)
    counts = {name: len(s.drain()) for name, s in subs.items()}
    assert counts["/scan"] == 20
    assert counts["/imu"] == 200
    assert counts["/wheels"] == 60
    assert counts["/battery"] == 2
    assert counts["/ground_truth"] >= 100  # every physics step (50 Hz) plus the first
    gt = bus.latest(GROUND_TRUTH)
    assert gt is not None and gt.frame_id == "map" and gt.pose == Pose2D(1.0, 2.0, 0.0)
    scan = bus.latest(SCAN)
    assert scan is not None and scan.frame_id == "laser" and len(scan.ranges_m) == 360
    health = bus.latest(HEALTH)
    assert health is not None and health.name == "simulator"
    assert health.counters["scans"] == 10 and health.counters["collisions"] == 0


async def test_imu_samples_keep_their_own_stamps_and_arrive_within_a_physics_period() -> None:
    """The simulated IMU hands over the samples of one physics period together: each is
    stamped at its own 100 Hz instant, never arrives before that instant, and arrives at most
    one physics period (20 ms) after it; none is lost or repeated."""
    _cfg, bus, clock, _world, sim, _base = make()
    sub = bus.subscribe(IMU, maxsize=1000)
    arrivals: list[tuple[float, float]] = []  # (stamp, clock time on arrival)

    async def watch() -> None:
        async for imu in sub:
            arrivals.append((imu.stamp, clock.now()))

    await run_parts(clock, [sim.run_physics, sim.run_imu, watch], 1.0)
    stamps = [s for s, _ in arrivals]
    assert len(stamps) == 100
    assert stamps[0] == pytest.approx(0.001)
    assert all(b - a == pytest.approx(0.01) for a, b in itertools.pairwise(stamps))
    assert all(-1e-9 <= t - s <= 0.02 for s, t in arrivals)
    assert len({t for _, t in arrivals}) == 50  # handed over once per physics period


async def test_simbase_drives_and_times_out() -> None:
    cfg, bus, clock, world, sim, base = make()
    servo = bus.subscribe(SERVO_CMD, maxsize=100)

    async def commander() -> None:
        for _ in range(10):  # 1 s of commands, then silence
            bus.publish(CMD_VEL, Twist(clock.now(), 0.2, 0.0))
            await clock.sleep(0.1)

    await run_parts(clock, [sim.run_physics, base.run, base.run_watchdog, commander], 3.0)
    sent = servo.drain()
    want = twist_to_servo_command(0.2, 0.0, RobotModel.from_config(cfg.robot), 0.0)
    assert sent[0].wheel_duty == want.wheel_duty
    assert sent[-1].wheel_duty == (0, 0, 0, 0, 0, 0)
    # The stop came 0.5 s (± one watchdog period) after the last command at t = 0.9 s.
    assert 1.4 <= sent[-1].stamp <= 1.46
    assert base.timed_out
    x_stop = world.truth_pose.x
    assert x_stop > 1.15
    assert world.truth_twist[0] == 0.0


async def test_halt_zeroes_the_wheels_and_keeps_steering() -> None:
    cfg, bus, clock, world, sim, base = make()
    bus.publish(CMD_VEL, Twist(0.0, 0.2, 0.5))

    async def halt_later() -> None:
        await clock.sleep(0.3)
        await base.halt()

    await run_parts(clock, [sim.run_physics, base.run, halt_later], 1.0)
    last = bus.latest(SERVO_CMD)
    assert last is not None and last.wheel_duty == (0, 0, 0, 0, 0, 0)
    robot = RobotModel.from_config(cfg.robot)
    assert last.steer_position == twist_to_servo_command(0.2, 0.5, robot, 0).steer_position
    assert world.truth_twist == (0.0, 0.0)


async def test_collision_event_published_once() -> None:
    _cfg, bus, clock, _world, sim, base = make()
    events = bus.subscribe(EVENTS)

    async def push() -> None:
        while True:
            bus.publish(CMD_VEL, Twist(clock.now(), 0.37, 0.0))
            await clock.sleep(0.1)

    await run_parts(clock, [sim.run_physics, base.run, base.run_watchdog, push], 20.0)
    kinds = [e.kind for e in events.drain()]
    assert kinds == ["collision"]


async def test_wheel_odometry_follows_truth_without_noise() -> None:
    cfg = Config()
    cfg.sim.noise.odom_scale_error = 0.0
    cfg.sim.noise.odom_heading_drift_rad_per_m = 0.0
    cfg, bus, clock, world, sim, base = make(cfg)
    odo = WheelOdometry(RobotModel.from_config(cfg.robot), bus, clock)

    async def commander() -> None:
        while True:
            bus.publish(CMD_VEL, Twist(clock.now(), 0.25, 0.15))
            await clock.sleep(0.1)

    await run_parts(clock, [sim.run_physics, sim.run_wheels, base.run, odo.run, commander], 8.0)
    est = bus.latest(WHEEL_ODOM)
    assert est is not None
    truth = world.truth_pose.relative_to(Pose2D(1.0, 2.0, 0.0))
    travelled = 0.25 * 1.04 * 8.0
    assert travelled > 1.5
    # Several passes through the dead zone on both mid wheels, and still within 2 % of the
    # distance (the corners scrub a little while the steering settles).
    assert odo.filters[0].suspect_readings > 5 and odo.filters[1].suspect_readings > 5
    assert est.pose.distance_to(truth) < 0.02 * travelled
    assert est.pose.yaw == pytest.approx(truth.yaw, abs=0.03)
