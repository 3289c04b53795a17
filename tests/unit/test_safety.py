"""The safety stage: limits, smoothing, watchdog, teleop precedence, stop zone, e-stop."""

from __future__ import annotations

import asyncio
import itertools
import math

import numpy as np
import pytest

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config, RobotConfig
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, OperatorCommand, Twist
from curio.core.topics import CMD_VEL, CMD_VEL_NAV, CMD_VEL_TELEOP, ESTOP, EVENTS, OPERATOR, SCAN
from curio.robot import RobotModel
from curio.safety.stage import SafetyStage
from curio.safety.stop_zone import StopZone, polygon_distances

ROBOT = RobotModel.from_config(RobotConfig())

FOOTPRINT = [(0.33, 0.31), (0.33, -0.31), (-0.33, -0.31), (-0.33, 0.31)]


def scan_of_points(stamp: float, points_base: list[tuple[float, float]], cfg: Config,
                   beams: int = 720) -> LaserScan:
    """A scan (laser frame) whose beams hit the given points (base_link); others see nothing."""
    lx, ly, lyaw = cfg.robot.laser_pose
    laser = Pose2D(lx, ly, lyaw)
    ranges = np.full(beams, np.inf, dtype=np.float32)
    inc = 2 * math.pi / beams
    for px, py in points_base:
        x, y = laser.inverse().transform_point(px, py)
        r = math.hypot(x, y)
        i = round((math.atan2(y, x) + math.pi) / inc) % beams
        ranges[i] = min(ranges[i], r)
    return LaserScan(stamp, -math.pi, inc, 0.15, 12.0, ranges)


def wall_ahead(x_m: float, half_width_m: float = 1.0) -> list[tuple[float, float]]:
    """Points of a wall across the path at ``x_m`` in base_link."""
    return [(x_m, float(y)) for y in np.arange(-half_width_m, half_width_m + 1e-9, 0.02)]


def make_stage(cfg: Config, clock: SimClock, bus: Bus) -> SafetyStage:
    stage = SafetyStage(cfg.nav.safety, RobotModel.from_config(cfg.robot), clock, bus)
    stage.on_scan(scan_of_points(clock.now(), [], cfg))
    return stage


async def run_cycles(stage: SafetyStage, clock: SimClock, n: int,
                     nav: tuple[float, float] | None = None,
                     teleop: tuple[float, float] | None = None) -> list[Twist]:
    """Step the stage ``n`` times at its rate, feeding fresh commands and an unchanged scan."""
    out = []
    period = 1.0 / stage.scfg.rate_hz
    for _ in range(n):
        await clock.advance(period)
        if nav is not None:
            stage.on_nav(Twist(clock.now(), *nav))
        if teleop is not None:
            stage.on_teleop(Twist(clock.now(), *teleop))
        stage._scan_stamp = clock.now()
        out.append(stage.step())
    return out


def test_fastest_wheel_matches_hardware_vectors() -> None:
    # In-place turn at 1 rad/s: the front corners are the fastest at 0.3655 m/s.
    assert ROBOT.fastest_wheel_speed_mps(0.0, 1.0) == pytest.approx(0.3655, abs=1e-3)
    assert ROBOT.fastest_wheel_speed_mps(0.2, 0.0) == pytest.approx(0.2)
    # The limiter acts above 1.012 rad/s in place and keeps the radius when it scales.
    v, w = ROBOT.limit_to_wheel_speed(0.0, 1.45, 0.37)
    assert w == pytest.approx(0.37 / 0.3655, rel=1e-3)
    v, w = ROBOT.limit_to_wheel_speed(0.4, 0.8, 0.37)
    assert v / w == pytest.approx(0.5)
    assert ROBOT.fastest_wheel_speed_mps(v, w) == pytest.approx(0.37)


def test_polygon_distance_signs() -> None:
    poly = np.array(FOOTPRINT)
    d = polygon_distances(np.array([[0.0, 0.0], [0.43, 0.0], [0.33, 0.51]]), poly)
    assert d[0] == pytest.approx(-0.31)
    assert d[1] == pytest.approx(0.10)
    assert d[2] == pytest.approx(0.20)


async def test_speed_and_wheel_limits(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    stage = make_stage(cfg, clock, bus)
    outs = await run_cycles(stage, clock, 40, nav=(1.0, 0.0))
    assert outs[-1].linear_mps == pytest.approx(cfg.nav.safety.max_speed_mps)
    stage2 = make_stage(cfg, clock, bus)
    outs = await run_cycles(stage2, clock, 40, nav=(0.0, 3.0))
    assert ROBOT.fastest_wheel_speed_mps(outs[-1].linear_mps, outs[-1].angular_radps) == \
        pytest.approx(cfg.robot.max_wheel_speed_mps, rel=1e-6)


async def test_acceleration_is_smoothed(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    stage = make_stage(cfg, clock, bus)
    outs = await run_cycles(stage, clock, 20, nav=(0.3, 0.0))
    dt = 1.0 / cfg.nav.safety.rate_hz
    steps = np.diff([0.0] + [o.linear_mps for o in outs])
    assert max(steps) <= cfg.nav.safety.max_accel_mps2 * dt + 1e-9
    assert outs[2].linear_mps < 0.3
    assert outs[-1].linear_mps == pytest.approx(0.3)


async def test_watchdog_ramps_to_zero_when_commands_stop(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    stage = make_stage(cfg, clock, bus)
    events = bus.subscribe(EVENTS)
    await run_cycles(stage, clock, 20, nav=(0.3, 0.0))
    outs = await run_cycles(stage, clock, 30)  # no more commands
    timeout_cycles = int(cfg.nav.safety.cmd_timeout_s * cfg.nav.safety.rate_hz)
    assert outs[timeout_cycles - 2].linear_mps == pytest.approx(0.3)  # still fresh
    assert outs[-1].linear_mps == 0.0
    speeds = [o.linear_mps for o in outs]
    assert all(a >= b for a, b in itertools.pairwise(speeds))  # a ramp, no jump up
    assert any(e.kind == "safety.watchdog" for e in events.drain())


async def test_teleop_takes_precedence_while_fresh(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    stage = make_stage(cfg, clock, bus)
    outs = await run_cycles(stage, clock, 30, nav=(0.3, 0.0), teleop=(0.0, 0.5))
    assert outs[-1].linear_mps == pytest.approx(0.0)
    assert outs[-1].angular_radps == pytest.approx(0.5)
    assert stage.last_source == "teleop"
    # Teleop goes quiet: after its deadman the navigator's command comes back.
    outs = await run_cycles(stage, clock, 30, nav=(0.3, 0.0))
    assert stage.last_source == "nav"
    assert outs[-1].linear_mps == pytest.approx(0.3)


def test_stop_zone_geometry() -> None:
    zone = StopZone(FOOTPRINT, stop_distance_m=0.1, slow_distance_m=0.5, lookahead_s=1.0)
    zone.set_points(np.array(wall_ahead(0.40)))  # 7 cm in front of the bumper
    assert zone.evaluate(0.3, 0.0).factor == 0.0  # forward: stop
    assert zone.evaluate(-0.3, 0.0).factor == 1.0  # reversing away: free
    zone.set_points(np.array(wall_ahead(0.63)))  # 30 cm ahead
    assert zone.evaluate(0.0, 1.0).factor == 1.0  # turning in place is never blocked here
    fwd = zone.evaluate(0.3, 0.0)
    assert 0.0 < fwd.factor < 1.0 and fwd.reason in ("slow", "stop")
    zone.set_points(np.array(wall_ahead(3.0)))  # far away: nothing to do
    assert zone.evaluate(0.3, 0.0).factor == 1.0
    # Something behind blocks reversing but not driving forward.
    zone.set_points(np.array([(-0.40, float(y)) for y in np.arange(-0.5, 0.5, 0.02)]))
    assert zone.evaluate(-0.3, 0.0).factor == 0.0
    assert zone.evaluate(0.3, 0.0).factor == 1.0


def test_stop_zone_lets_the_rover_through_a_tight_gap() -> None:
    zone = StopZone(FOOTPRINT, stop_distance_m=0.1, slow_distance_m=0.5, lookahead_s=1.0)
    # Posts 5 cm beside each flank (a doorway of footprint width + 0.1 m): driving straight on
    # is allowed; only contact within the lookahead would stop it.
    posts = [(x, s * 0.36) for x in np.arange(-0.2, 0.6, 0.02) for s in (-1.0, 1.0)]
    zone.set_points(np.array(posts))
    assert zone.evaluate(0.3, 0.0).factor > 0.0
    # Swerving into a post 5 cm away is stopped.
    assert zone.evaluate(0.3, 0.6).factor < 0.5


async def test_stop_zone_stops_before_a_wall_and_publishes_event(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    stage = SafetyStage(cfg.nav.safety, RobotModel.from_config(cfg.robot), clock, bus)
    events = bus.subscribe(EVENTS)
    # Simulate: the rover drives at the commanded speed towards a wall 1.5 m ahead.
    wall_x = 1.5
    travelled = 0.0
    period = 1.0 / cfg.nav.safety.rate_hz
    for _ in range(200):
        await clock.advance(period)
        pts = wall_ahead(wall_x - travelled)
        stage.on_scan(scan_of_points(clock.now(), pts, cfg))
        stage.on_nav(Twist(clock.now(), 0.3, 0.0))
        out = stage.step()
        travelled += out.linear_mps * period
    gap = wall_x - travelled - 0.33
    assert stage.last_output.linear_mps == pytest.approx(0.0, abs=1e-3)
    # It stops outside the margin, and not absurdly early.
    assert cfg.nav.safety.stop_distance_m <= gap <= cfg.nav.safety.stop_distance_m + 0.08
    assert any(e.kind == "safety.stop_zone" for e in events.drain())
    # Reversing away is allowed at once.
    outs = await run_cycles(stage, clock, 10, nav=(-0.2, 0.0))
    assert outs[-1].linear_mps < -0.1


async def test_no_scan_holds_the_rover(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    stage = SafetyStage(cfg.nav.safety, RobotModel.from_config(cfg.robot), clock, bus)
    period = 1.0 / cfg.nav.safety.rate_hz
    for _ in range(40):
        await clock.advance(period)
        stage.on_nav(Twist(clock.now(), 0.3, 0.0))
        out = stage.step()
    assert out.linear_mps == 0.0
    assert stage.health().state == "error"


async def test_estop_latches_through_the_bus(cfg: Config) -> None:
    from curio.core.topics import make_bus

    bus = make_bus()
    clock = SimClock()
    stage = SafetyStage(cfg.nav.safety, RobotModel.from_config(cfg.robot), clock, bus)
    cmd_sub = bus.subscribe(CMD_VEL, maxsize=1000)
    estop_sub = bus.subscribe(ESTOP)
    events = bus.subscribe(EVENTS)
    task = asyncio.create_task(stage.run())

    async def feed(seconds: float, v: float, teleop: bool = False) -> None:
        end = clock.now() + seconds
        while clock.now() < end:
            bus.publish(SCAN, scan_of_points(clock.now(), [], cfg))
            bus.publish(CMD_VEL_TELEOP if teleop else CMD_VEL_NAV, Twist(clock.now(), v, 0.0))
            await clock.advance(0.05)

    await feed(1.5, 0.3)
    assert cmd_sub.drain()[-1].linear_mps == pytest.approx(0.3)
    bus.publish(OPERATOR, OperatorCommand(clock.now(), "estop", source="test"))
    await feed(1.0, 0.3)
    outs = cmd_sub.drain()
    assert outs[-1].linear_mps == 0.0
    assert all(o.linear_mps == 0.0 for o in outs[2:])
    states = [m.engaged for m in estop_sub.drain()]
    assert states[-1] is True
    await feed(1.0, 0.3, teleop=True)  # teleop cannot override a latched e-stop
    assert all(o.linear_mps == 0.0 for o in cmd_sub.drain())
    assert stage.health().state == "error"
    bus.publish(OPERATOR, OperatorCommand(clock.now(), "release_estop", source="test"))
    await feed(1.5, 0.3)
    assert cmd_sub.drain()[-1].linear_mps == pytest.approx(0.3)
    assert estop_sub.drain()[-1].engaged is False
    kinds = [e.kind for e in events.drain()]
    assert kinds.count("safety.estop") == 2
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_estop_stops_in_the_same_loop_turn_even_after_a_flood(cfg: Config) -> None:
    """The e-stop does not wait for the next control cycle: published mid-cycle behind 1000
    other operator commands, the stage latches it and publishes a zero /cmd_vel at the
    command's own stamp (no simulated time passes); commands queued before a release are
    ignored after it."""
    from curio.core.topics import make_bus

    bus = make_bus()
    clock = SimClock()
    stage = SafetyStage(cfg.nav.safety, RobotModel.from_config(cfg.robot), clock, bus)
    cmd_sub = bus.subscribe(CMD_VEL, maxsize=1000)
    estop_sub = bus.subscribe(ESTOP)
    task = asyncio.create_task(stage.run())
    period = 1.0 / cfg.nav.safety.rate_hz
    for _ in range(30):
        bus.publish(SCAN, scan_of_points(clock.now(), [], cfg))
        bus.publish(CMD_VEL_NAV, Twist(clock.now(), 0.3, 0.0))
        await clock.advance(period)
    await clock.advance(period / 2)  # mid-cycle
    assert cmd_sub.drain()[-1].linear_mps > 0.1
    estop_sub.drain()
    for _ in range(1000):
        bus.publish(OPERATOR, OperatorCommand(clock.now(), "pause", source="web:flood"))
    pressed_s = clock.now()
    bus.publish(OPERATOR, OperatorCommand(pressed_s, "estop", source="web:alice"))
    for _ in range(5):  # a few turns of the event loop, no simulated time
        await clock.sleep(0)
    assert clock.now() == pressed_s
    (state,) = estop_sub.drain()
    assert state.engaged and state.source == "web:alice" and state.stamp == pressed_s
    zero = cmd_sub.drain()
    assert zero and zero[-1].linear_mps == 0.0 and zero[-1].stamp == pressed_s
    # A nav command stamped before the release must not move the rover after it.
    stale = Twist(clock.now(), 0.3, 0.0)
    await clock.advance(period)
    bus.publish(OPERATOR, OperatorCommand(clock.now(), "release_estop", source="web:alice"))
    bus.publish(CMD_VEL_NAV, stale)
    await clock.advance(3 * period)
    assert all(o.linear_mps == 0.0 for o in cmd_sub.drain())
    assert estop_sub.drain()[-1].source == "web:alice"
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_the_docking_allowance_is_for_the_docker_not_for_teleop(cfg: Config,
                                                                      bus: Bus) -> None:
    """While docking, the stop zone keeps only 5 mm to what is ahead, for the docker's own
    slow approach. An operator driving by hand meanwhile gets the whole stop zone: in the soak
    of 2026-12-07 (seed 2) a teleop command 1 cm before the dock drove the rover into it."""
    clock = SimClock()
    stage = make_stage(cfg, clock, bus)
    front_m = max(x for x, _ in stage.robot.footprint_points)
    dock_face = wall_ahead(front_m + 0.03, half_width_m=0.3)

    async def drive(**command: tuple[float, float]) -> float:
        period = 1.0 / stage.scfg.rate_hz
        out = 0.0
        for _ in range(20):
            await clock.advance(period)
            stage.allow_docking(clock.now() + 0.3, 0.065)
            stage.on_scan(scan_of_points(clock.now(), dock_face, cfg))
            if "nav" in command:
                stage.on_nav(Twist(clock.now(), *command["nav"]))
            if "teleop" in command:
                stage.on_teleop(Twist(clock.now(), *command["teleop"]))
            out = max(out, stage.step().linear_mps)
        return out

    assert await drive(nav=(0.05, 0.0)) > 0.02  # the docker closes on its dock
    await run_cycles(stage, clock, 20, nav=(0.0, 0.0))
    assert await drive(teleop=(0.06, 0.0)) == 0.0  # a hand on the joystick does not
