"""The dock: home and dock as one pose, the dock's shape in the simulator and in the map, the
lidar's fit of it, and the final approach law."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from curio.app import App
from curio.bt.paths import PathManager
from curio.core.clock import SimClock
from curio.core.config import load_config
from curio.core.geometry import Pose2D, wrap_angle
from curio.docking.approach import ENTRY_X_M, DockApproach
from curio.docking.home import HomeDock, seed_home
from curio.docking.perception import DockDetector
from curio.docking.station import DockShape, stamp_dock
from curio.estimation.maps import load_map
from curio.robot import RobotModel
from curio.sim.world import World


def test_home_is_path_zeros_last_waypoint_and_the_start_pose(tmp_path: Path) -> None:
    cfg = load_config(None, [f'data_dir="{tmp_path}"', "web.enabled=false"])
    paths = PathManager(cfg.bt.paths, cfg.data_path(cfg.bt.paths_file))
    home = HomeDock(paths, 0.7)
    assert home.pose() == Pose2D(0.0, 0.0, 0.0)
    home.set(Pose2D(1.5, -2.0, math.pi / 2))
    staging = home.staging()
    assert staging.x == pytest.approx(1.5) and staging.y == pytest.approx(-2.7)
    # A restart starts there: the robot model, the simulator and the localiser all take it.
    app = App(cfg, SimClock(), web=False)
    assert app.robot.home == Pose2D(1.5, -2.0, round(math.pi / 2, 6))
    assert app.world is not None and app.world.truth_pose.distance_to(app.robot.home) < 1e-9
    assert app.localizer is not None and app.localizer.start == app.robot.home
    assert app.paths.get(0).waypoints[-1].x_m == 1.5  # Go Home drives there


def test_robot_home_seeds_home_only_the_first_time(tmp_path: Path) -> None:
    cfg = load_config(None, [f'data_dir="{tmp_path}"', "robot.home=[2.0, 1.0, 0.5]"])
    paths = PathManager(cfg.bt.paths, cfg.data_path("p.json"))
    seed_home(paths, cfg, fresh=True)
    assert HomeDock(paths, 0.7).pose() == Pose2D(2.0, 1.0, 0.5)
    paths.set_home(3.0, 3.0, 0.0)  # moved on the dashboard later
    seed_home(PathManager(cfg.bt.paths, cfg.data_path("p.json")), cfg, fresh=False)
    again = PathManager(cfg.bt.paths, cfg.data_path("p.json"))
    assert HomeDock(again, 0.7).pose() == Pose2D(3.0, 3.0, 0.0)


def _world_with_dock(tmp_path: Path) -> tuple[World, RobotModel]:
    cfg = load_config(None, [f'data_dir="{tmp_path}"', "dock.enabled=true"])
    robot = RobotModel.from_config(cfg.robot)
    return World.from_config(cfg, robot), robot


def test_a_time_lapse_charges_a_docked_rover_only(tmp_path: Path) -> None:
    """The soak jumps the building's clock while the rover is parked (the world is not
    stepped): on the dock's contact the charger charges over the lapse, at its rate; off it
    nothing changes (SoakHooks.on_lapse)."""
    world, _ = _world_with_dock(tmp_path)
    world.set_battery_voltage(7.0)
    world.lapse(3600.0)  # docked, an hour at dock.charge_rate_v_per_h (0.5 V/h)
    assert world.battery_voltage() == pytest.approx(7.5, abs=1e-6)
    world.teleport(Pose2D(-0.5, 0.0, 0.0))
    world.lapse(3600.0)
    assert world.battery_voltage() == pytest.approx(7.5, abs=1e-6)


def test_the_simulated_dock_blocks_charges_and_is_drawn_into_the_map(tmp_path: Path) -> None:
    world, robot = _world_with_dock(tmp_path)
    dock = world.dock
    assert dock is not None and world.docked and world.charger_voltage() == 9.0
    assert not world.collides(Pose2D(0.0, 0.0, 0.0))  # docked: the contacts bridge the gap
    assert world.collides(Pose2D(0.05, 0.0, 0.0))  # 5 cm further: against the dock
    world.teleport(Pose2D(-0.03, 0.0, 0.0))
    assert not world.docked and world.charger_voltage() == 0.0
    world.teleport(Pose2D(0.0, 0.0, 0.0))
    world.set_battery_voltage(6.5)
    for _ in range(100):
        world.step(0.1)
    assert world.battery_voltage() > 6.5  # charging
    grid = stamp_dock(load_map(Path(__file__).parents[2] / "maps" / "curio_building.yaml"),
                      Pose2D(), DockShape.for_footprint(robot.footprint))
    inv = grid.origin.inverse()
    for x, y, occupied in ((0.45, 0.3, True), (0.40, 0.0, False), (0.52, 0.0, True),
                           (0.2, 0.0, False)):
        lx, ly = inv.transform_point(x, y)
        assert (grid.data[int(ly / 0.05), int(lx / 0.05)] == 100) == occupied, (x, y)


def test_the_lidar_finds_the_dock_from_the_staging_pose(tmp_path: Path) -> None:
    world, robot = _world_with_dock(tmp_path)
    det = DockDetector(DockShape.for_footprint(robot.footprint))
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(30):
        truth = Pose2D(-0.7 + rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3),
                       math.radians(rng.uniform(-15, 15)))
        world.teleport(truth)
        true_dock = truth.inverse()
        guess = true_dock @ Pose2D(*rng.normal(0.0, 0.05, 3))  # what the map says
        fix = det.detect(world.cast_scan(0.0).points(robot.laser_in_base), guess)
        assert fix is not None
        err = fix.dock_in_base.relative_to(true_dock)
        errors.append((math.hypot(err.x, err.y), abs(math.degrees(err.yaw))))
    worst = np.max(errors, axis=0)
    assert worst[0] < 0.03 and worst[1] < 3.0  # one scan; the docker smooths them
    # Without the dock (a plain wall ahead) there is nothing to fit.
    world.set_dock(None)
    world.teleport(Pose2D(-0.7, 0.0, 0.0))
    assert det.detect(world.cast_scan(0.0).points(robot.laser_in_base), Pose2D(0.7, 0, 0)) \
        is None


def _drive(law: DockApproach, start: Pose2D, dt: float = 0.05) -> tuple[Pose2D, str]:
    pose, t = start, 0.0
    while t < 120.0:
        step = law.step(pose, t)
        if step.done or step.retry:
            return pose, step.retry
        v, w = step.linear_mps, step.angular_radps
        pose = Pose2D(pose.x + v * math.cos(pose.yaw) * dt, pose.y + v * math.sin(pose.yaw) * dt,
                      wrap_angle(pose.yaw + w * dt))
        t += dt
    raise AssertionError("the approach did not end")


@pytest.mark.parametrize("start", [Pose2D(-0.7, 0.0, 0.0), Pose2D(-1.0, 0.3, 0.26),
                                   Pose2D(-0.45, -0.29, -0.26), Pose2D(-0.9, 0.2, -0.26)])
def test_the_approach_law_ends_on_the_stop_line_on_the_axis(start: Pose2D) -> None:
    law = DockApproach(0.06, 0.02, 0.012, 0.026)
    end, retry = _drive(law, start)
    assert retry == "" and abs(end.x) < 0.005 and abs(end.y) < 0.006
    assert abs(math.degrees(end.yaw)) < 1.0


def test_the_approach_retries_when_it_cannot_make_it() -> None:
    law = DockApproach(0.06, 0.02, 0.012, 0.026)
    assert law.step(Pose2D(ENTRY_X_M + 0.2, 0.0, 0.0), 0.0).retry  # starts too close
    law.reset()
    law.phase = "final"
    step = law.step(Pose2D(-0.05, 0.05, 0.0), 10.0)  # 5 cm off with 5 cm to go
    assert "off the dock's axis" in step.retry
