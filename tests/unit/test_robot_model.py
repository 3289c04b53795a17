"""One robot model: a changed wheel track or footprint in the config reaches every part."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.clock import SimClock
from curio.core.config import Config, RobotConfig
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, Twist
from curio.core.topics import CMD_VEL_NAV, SCAN, make_bus
from curio.drivers.kinematics import inverse_kinematics
from curio.estimation.maps import OccupancyGrid
from curio.nav.controller import LocalController
from curio.nav.costmap import Costmap
from curio.robot import RobotModel
from curio.safety.stage import SafetyStage

WIDE_FOOTPRINT = [(0.45, 0.45), (0.45, -0.45), (-0.45, -0.45), (-0.45, 0.45)]


def wide_config() -> Config:
    """Curio with a 0.80 m mid-wheel track, 0.76 m corner track and a 0.9 m square body."""
    robot = RobotConfig(mid_wheel_track_m=0.80, corner_wheel_track_m=0.76,
                        footprint=WIDE_FOOTPRINT)
    return Config(robot=robot)


def test_the_base_kinematics_follow_the_wheel_track() -> None:
    for cfg in (Config(), wide_config()):
        robot = RobotModel.from_config(cfg.robot)
        speeds, _ = inverse_kinematics(0.0, 0.5, robot)
        # Turning in place: the middle wheels roll at ω · track / 2.
        assert abs(speeds[1]) == pytest.approx(0.5 * cfg.robot.mid_wheel_track_m / 2.0)


async def test_the_safety_limiter_follows_the_wheel_track() -> None:
    turns = []
    for cfg in (Config(), wide_config()):
        robot = RobotModel.from_config(cfg.robot)
        clock = SimClock()
        bus = make_bus()
        stage = SafetyStage(cfg.nav.safety, robot, clock, bus)
        out = Twist(0.0)
        for k in range(40):  # 2 s at 20 Hz: the acceleration ramps are done
            now = k / cfg.nav.safety.rate_hz
            await clock.advance(now - clock.now())
            empty = np.full(360, np.inf, dtype=np.float32)
            stage.on_scan(LaserScan(now, -math.pi, 2 * math.pi / 360, 0.15, 12.0, empty))
            stage.on_nav(Twist(now, 0.0, 1.45))
            out = stage.step()
        # Turning in place as fast as allowed: the fastest wheel is at its limit, and the
        # corner wheels of the wider rover are further out, so it turns slower.
        assert robot.fastest_wheel_speed_mps(out.linear_mps, out.angular_radps) == \
            pytest.approx(cfg.robot.max_wheel_speed_mps, rel=1e-6)
        turns.append(out.angular_radps)
    # Turning in place, the fastest wheel is the corner furthest from base_link:
    # ω = 0.37 / hypot(0.28, track/2) — 1.012 rad/s for the default track, 0.784 for the wide.
    assert turns == pytest.approx([0.37 / math.hypot(0.28, 0.235),
                                   0.37 / math.hypot(0.28, 0.38)], rel=1e-6)


def test_the_controller_speed_cap_on_an_arc_follows_the_wheel_track() -> None:
    speeds = []
    for cfg in (Config(), wide_config()):
        robot = RobotModel.from_config(cfg.robot)
        ctrl = LocalController(cfg.nav.controller, robot, None)
        radius = 1.0  # a circle the pure-pursuit arc follows, κ ≈ 1/m
        t = np.linspace(0.0, math.pi, 400)
        plan = [Pose2D(radius * math.sin(a), radius * (1.0 - math.cos(a)), a) for a in t]
        ctrl.set_plan(plan)
        pose = Pose2D(0.0, 0.0, 0.0)
        v = w = 0.0
        for k in range(30):
            out = ctrl.compute(pose, k * ctrl.dt_s)
            v, w = out.linear_mps, out.angular_radps
            pose = pose @ Pose2D(v * ctrl.dt_s, 0.0, w * ctrl.dt_s)
        kappa = w / v
        assert v <= robot.max_speed_on_arc_mps(kappa) + 1e-9
        assert v == pytest.approx(robot.max_speed_on_arc_mps(kappa), rel=0.05)
        speeds.append(v)
    assert speeds[1] < speeds[0] - 0.01


def test_the_costmap_follows_the_footprint() -> None:
    data = np.zeros((100, 100), dtype=np.int8)
    data[:, 50] = 100  # a wall along x = 2.5 m
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
    cells = []
    for cfg in (Config(), wide_config()):
        cm = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
        pad = cfg.nav.costmap.footprint_padding_m
        half = max(abs(y) for _, y in cfg.robot.footprint)
        assert cm.inscribed_radius_m == pytest.approx(half + pad)
        cells.append(int((cm.costs()[50, :50] >= 253).sum()))
    # The wider footprint keeps its centre further from the wall.
    assert cells[1] > cells[0] + 2


def test_the_safety_stop_zone_follows_the_footprint() -> None:
    for cfg, stops in ((Config(), False), (wide_config(), True)):
        robot = RobotModel.from_config(cfg.robot)
        stage = SafetyStage(cfg.nav.safety, robot, SimClock(), make_bus())
        # A point 0.45 m to the left of base_link, beside the path: the default body (0.31 m
        # half width) passes it, the wide one (0.45 m) would touch it.
        stage.zone.set_points(np.array([[0.8, 0.42]]))
        assert (stage.zone.evaluate(0.3, 0.0).factor < 1.0) is stops


async def test_the_app_builds_every_part_from_one_model(tmp_path: object) -> None:
    from curio.app import App

    cfg = wide_config().model_copy(update={"data_dir": str(tmp_path)})
    app = App(cfg, SimClock(), web=False)
    assert app.costmap.robot is app.robot
    assert app.safety.robot is app.robot
    assert app.controller.robot is app.robot
    assert app.world is not None and app.world.robot is app.robot
    bus = app.bus
    assert bus.latest(SCAN) is None and bus.latest(CMD_VEL_NAV) is None
