"""The local controller: following, turning in place, goal checker, avoidance, progress."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D, wrap_angle
from curio.estimation.maps import OccupancyGrid
from curio.nav.controller import ControlStatus, LocalController, ProgressChecker
from curio.nav.costmap import Costmap
from curio.robot import RobotModel


def open_grid(size_m: float = 8.0, res: float = 0.05) -> OccupancyGrid:
    """An empty room with walls, origin at (-size/2, -size/2)."""
    n = int(size_m / res)
    data = np.zeros((n, n), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return OccupancyGrid(data, res, Pose2D(-size_m / 2, -size_m / 2, 0.0))


def straight_plan(x0: float, x1: float, y: float = 0.0, step: float = 0.05) -> np.ndarray:
    xs = np.arange(x0, x1 + 1e-9, step)
    return np.stack([xs, np.full_like(xs, y), np.zeros_like(xs)], axis=1)


def drive_arc(pose: Pose2D, v: float, w: float, dt: float) -> Pose2D:
    """``pose`` (map) after driving ``v`` m/s at ``w`` rad/s for ``dt`` s (an exact arc)."""
    if abs(w) < 1e-9:
        return Pose2D(pose.x + v * dt * math.cos(pose.yaw), pose.y + v * dt * math.sin(pose.yaw),
                      pose.yaw)
    r = v / w
    th = pose.yaw + w * dt
    return Pose2D(pose.x + r * (math.sin(th) - math.sin(pose.yaw)),
                  pose.y - r * (math.cos(th) - math.cos(pose.yaw)), wrap_angle(th))


def drive(ctrl: LocalController, pose: Pose2D, seconds: float,
          stop_on_done: bool = True) -> tuple[Pose2D, list]:
    """Integrate unicycle kinematics under the controller; return the final pose and log."""
    dt = ctrl.dt_s
    log = []
    t = 0.0
    for _ in range(int(seconds / dt)):
        out = ctrl.compute(pose, t)
        log.append((t, pose, out))
        if stop_on_done and out.status in (ControlStatus.GOAL_REACHED, ControlStatus.BLOCKED,
                                           ControlStatus.NO_PROGRESS):
            break
        pose = drive_arc(pose, out.linear_mps, out.angular_radps, dt)
        t += dt
    return pose, log


@pytest.fixture
def ctrl(cfg: Config) -> LocalController:
    cm = Costmap(open_grid(), RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    c = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm)
    return c


def test_follows_a_straight_plan_within_limits(ctrl: LocalController, cfg: Config) -> None:
    ctrl.set_plan(straight_plan(-2.0, 2.0), Pose2D(2.0, 0.0, 0.0))
    pose, log = drive(ctrl, Pose2D(-2.0, 0.0, 0.0), 40.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert pose.distance_to(Pose2D(2.0, 0.0)) <= cfg.nav.controller.xy_goal_tolerance_m
    speeds = [o.linear_mps for _, _, o in log]
    assert max(speeds) <= cfg.nav.controller.max_speed_mps + 1e-9
    assert max(speeds) >= 0.9 * cfg.nav.controller.max_speed_mps  # it does get up to speed
    dv = np.diff(speeds)
    assert dv.max() <= cfg.nav.controller.max_accel_mps2 * ctrl.dt_s + 1e-9
    # 4 m at 0.3 m/s is 13.3 s; accelerating and the approach cost little more.
    assert log[-1][0] < 1.3 * 4.0 / cfg.nav.controller.max_speed_mps


def test_turns_in_place_when_facing_away(ctrl: LocalController, cfg: Config) -> None:
    ctrl.set_plan(straight_plan(0.0, 2.0), Pose2D(2.0, 0.0, 0.0))
    _pose, log = drive(ctrl, Pose2D(0.0, 0.0, math.pi), 40.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    first = [o for _, _, o in log[:10]]
    assert all(o.linear_mps == 0.0 for o in first)
    assert all(abs(o.angular_radps) > 0 for o in first[1:])
    assert first[1].status is ControlStatus.ROTATING
    # It did not wander off backwards: the path stays near the line.
    assert max(abs(p.y) for _, p, _ in log) < 0.2


def test_never_drives_arcs_tighter_than_the_servo_limit(ctrl: LocalController,
                                                         cfg: Config) -> None:
    # An L-shaped plan forces a sharp turn.
    a = straight_plan(-2.0, 0.0)
    ys = np.arange(0.05, 2.0, 0.05)
    b = np.stack([np.zeros_like(ys), ys, np.full_like(ys, math.pi / 2)], axis=1)
    ctrl.set_plan(np.vstack([a, b]), Pose2D(0.0, 2.0, math.pi / 2))
    _pose, log = drive(ctrl, Pose2D(-2.0, 0.0, 0.0), 60.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    for _, _, o in log:
        if o.linear_mps > 1e-6 and abs(o.angular_radps) > 1e-9:
            assert abs(o.linear_mps / o.angular_radps) >= \
                cfg.nav.controller.min_turning_radius_m - 1e-6


def test_final_heading_is_met(ctrl: LocalController, cfg: Config) -> None:
    ctrl.set_plan(straight_plan(0.0, 1.5), Pose2D(1.5, 0.0, math.pi / 2))
    pose, log = drive(ctrl, Pose2D(0.0, 0.0, 0.0), 40.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert abs(wrap_angle(pose.yaw - math.pi / 2)) <= cfg.nav.controller.yaw_goal_tolerance_rad
    # Without a heading (NaN yaw) it stops as soon as the position is reached.
    ctrl.reset()
    ctrl.set_plan(straight_plan(0.0, 1.5), Pose2D(1.5, 0.0, math.nan))
    pose, log = drive(ctrl, Pose2D(0.0, 0.0, 0.0), 40.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert abs(pose.yaw) < 0.3


def test_avoids_an_unmapped_obstacle_or_reports_blocked(cfg: Config) -> None:
    grid = open_grid()
    cm = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    # A wall across the whole room at x = 1 (as the obstacle layer would mark it).
    blocked = grid.data.copy()
    col = int((1.0 - grid.origin.x) / grid.resolution_m)
    blocked[:, col] = 100
    cm.set_static_map(OccupancyGrid(blocked, grid.resolution_m, grid.origin))
    ctrl = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm)
    ctrl.set_plan(straight_plan(-2.0, 2.5), Pose2D(2.5, 0.0, 0.0))
    pose, log = drive(ctrl, Pose2D(-2.0, 0.0, 0.0), 60.0)
    assert log[-1][2].status is ControlStatus.BLOCKED
    # It stopped short of the wall: the footprint never overlapped it.
    assert pose.x + 0.33 < 1.0
    # A box grazing the swept path, with room beside it: the controller swerves round it
    # without touching it (a box squarely on the plan is the global planner's job).
    box = grid.data.copy()
    r0 = int((0.3 - grid.origin.y) / grid.resolution_m)
    c0 = int((0.3 - grid.origin.x) / grid.resolution_m)
    box[r0:r0 + 6, c0:c0 + 6] = 100
    cm2 = Costmap(OccupancyGrid(box, grid.resolution_m, grid.origin),
                  RobotModel.from_config(cfg.robot),
                  cfg.nav.costmap)
    ctrl2 = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm2)
    ctrl2.set_plan(straight_plan(-2.0, 2.5), Pose2D(2.5, 0.0, 0.0))
    pose, log = drive(ctrl2, Pose2D(-2.0, 0.0, 0.0), 80.0)
    poses = np.array([[p.x, p.y, p.yaw] for _, p, _ in log])
    assert (cm2.footprint_costs(poses) < 254).all()
    assert any(o.status is ControlStatus.AVOIDING for _, _, o in log)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED


def test_progress_checker(cfg: Config) -> None:
    pc = ProgressChecker(0.1, 10.0)
    assert pc.update(Pose2D(0, 0, 0), 0.0)
    assert pc.update(Pose2D(0.05, 0, 0), 9.0)
    assert not pc.update(Pose2D(0.05, 0, 0), 10.5)
    assert pc.update(Pose2D(0.2, 0, 0), 11.0)  # moving again resets it
    assert pc.update(Pose2D(0.2, 0, 0.6), 30.0)  # turning counts as progress


def test_no_progress_when_the_rover_does_not_move(ctrl: LocalController, cfg: Config) -> None:
    ctrl.set_plan(straight_plan(0.0, 3.0), Pose2D(3.0, 0.0, 0.0))
    out = None
    for k in range(int((cfg.nav.controller.progress_timeout_s + 1.0) / ctrl.dt_s)):
        out = ctrl.compute(Pose2D(0.0, 0.0, 0.0), k * ctrl.dt_s)  # wheels spin, nothing moves
    assert out is not None and out.status is ControlStatus.NO_PROGRESS
    assert out.linear_mps == 0.0


def test_idle_without_a_plan(ctrl: LocalController) -> None:
    out = ctrl.compute(Pose2D(), 0.0)
    assert out.status is ControlStatus.IDLE and out.linear_mps == 0.0


def test_backs_out_where_it_cannot_turn_in_place(cfg: Config) -> None:
    grid = open_grid()
    res = grid.resolution_m
    # A dead-end alcove 0.8 m wide and 0.9 m deep, open towards −x; the rover in it facing
    # its end. The goal is behind it: the corners cannot swing round inside the alcove.
    def rc(x: float, y: float) -> tuple[int, int]:
        return int((y - grid.origin.y) / res), int((x - grid.origin.x) / res)

    r_lo, c0 = rc(-0.45, -0.45)
    r_hi, c1 = rc(0.5, 0.45)
    data = grid.data.copy()
    data[r_lo - 2:r_lo, c0:c1 + 2] = 100  # lower wall
    data[r_hi:r_hi + 2, c0:c1 + 2] = 100  # upper wall
    data[r_lo - 2:r_hi + 2, c1:c1 + 2] = 100  # the end
    cm = Costmap(OccupancyGrid(data, res, grid.origin), RobotModel.from_config(cfg.robot),
                 cfg.nav.costmap)
    ctrl = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm)
    start = Pose2D(0.05, 0.0, 0.0)
    assert cm.footprint_cost(start) < 254
    xs = np.arange(0.05, -2.5, -0.05)
    plan = np.stack([xs, np.zeros_like(xs), np.full_like(xs, math.pi)], axis=1)
    ctrl.set_plan(plan, Pose2D(-2.5, 0.0, math.nan))
    _pose, log = drive(ctrl, start, 80.0)
    poses = np.array([[p.x, p.y, p.yaw] for _, p, _ in log])
    assert (cm.footprint_costs(poses) < 254).all()  # never touched the alcove
    assert any(o.linear_mps < 0 for _, _, o in log)  # it backed out ...
    assert log[-1][2].status is ControlStatus.GOAL_REACHED  # ... and got there


def door_grid(gap_m: float, size_m: float = 8.0, res: float = 0.05) -> OccupancyGrid:
    """An open room with a wall across x = 1 m and a door of ``gap_m`` centred on y = 0."""
    grid = open_grid(size_m, res)
    data = grid.data.copy()
    n = data.shape[0]
    col = int((1.0 + size_m / 2) / res)
    ys = (np.arange(n) + 0.5) * res - size_m / 2
    data[np.abs(ys) > gap_m / 2, col:col + 2] = 100
    return OccupancyGrid(data, res, grid.origin)


@pytest.mark.parametrize(("gap_m", "narrow"), [(0.8, True), (3.0, False)])
def test_turns_in_place_sooner_before_a_narrow_passage(cfg: Config, gap_m: float,
                                                       narrow: bool) -> None:
    """A heading error of 0.6 rad (between narrow_rotate_enter_rad and rotate_enter_rad):
    before a door narrower than twice the circumscribed radius the rover turns in place to
    line up with the plan; before a wide one it drives an arc."""
    c = cfg.nav.controller
    assert c.narrow_rotate_enter_rad < 0.6 < c.rotate_enter_rad
    cm = Costmap(door_grid(gap_m), RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    ctrl = LocalController(c, RobotModel.from_config(cfg.robot), cm)
    ctrl.set_plan(straight_plan(0.4, 2.5), Pose2D(2.5, 0.0, 0.0))
    out = ctrl.compute(Pose2D(0.4, 0.0, 0.6), 0.0)
    if narrow:
        assert out.status is ControlStatus.ROTATING
        assert out.linear_mps == 0.0 and out.angular_radps < 0.0
    else:
        assert out.status is ControlStatus.FOLLOWING


def test_enters_a_narrow_door_aligned(cfg: Config) -> None:
    """Started at an angle to a door only 0.8 m wide, the rover lines up and drives through."""
    cm = Costmap(door_grid(0.8), RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    ctrl = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm)
    ctrl.set_plan(straight_plan(-0.5, 2.5), Pose2D(2.5, 0.0, 0.0))
    _pose, log = drive(ctrl, Pose2D(-0.5, 0.0, 0.7), 60.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    at_door = [p for _, p, _ in log if 0.7 <= p.x <= 1.3]
    assert at_door and max(abs(wrap_angle(p.yaw)) for p in at_door) < 0.3
    assert max(abs(p.y) for p in at_door) < 0.1


def wall_grid(size_m: float = 8.0, res: float = 0.05) -> OccupancyGrid:
    """An open room with a long wall along y = -0.40 m (its face at -0.35 m), x from -3 to 3."""
    grid = open_grid(size_m, res)
    data = grid.data.copy()
    row = int((-0.40 + size_m / 2) / res)
    data[row - 1:row + 1, int(1.0 / res):int(7.0 / res)] = 100
    return OccupancyGrid(data, res, grid.origin)


def wedged(cfg: Config) -> tuple[Costmap, LocalController, Pose2D]:
    """The rover beside the wall, its right side a few centimetres from it, heading 0.03 rad
    away from it (where a soak's rover backed in and stayed for 1.6 simulated hours), with
    the goal behind it: it cannot turn in place (its corners would sweep into the wall)."""
    cm = Costmap(wall_grid(), RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    ctrl = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm)
    start = Pose2D(0.0, 0.0, 0.03)
    goal = Pose2D(-2.5, 1.0, math.nan)
    n = 60
    plan = np.stack([np.linspace(start.x, goal.x, n), np.linspace(start.y, goal.y, n),
                     np.full(n, math.atan2(goal.y - start.y, goal.x - start.x))], axis=1)
    ctrl.set_plan(plan, goal)
    assert ctrl._rotation_blocked(start, 2.0)  # the premise: no room to turn where it stands
    return cm, ctrl, start


def test_drives_out_of_a_wedge_beside_a_wall(cfg: Config) -> None:
    """Wedged along a wall with the goal behind, the rover finds the gentle arc along which it
    gets room to turn, drives it, turns and reaches the goal, never touching the wall (it
    used to stop: no admissible motion)."""
    cm, ctrl, start = wedged(cfg)
    _pose, log = drive(ctrl, start, 90.0)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    poses = np.array([[p.x, p.y, p.yaw] for _, p, _ in log])
    assert (cm.footprint_costs(poses) < 254).all()
    assert any(o.detail == "driving on to make room to turn" for _, _, o in log)


def test_the_way_out_of_a_wedge_is_one_the_safety_stage_allows(cfg: Config) -> None:
    """The manoeuvre drives only arcs the safety stage's stop zone would let through (asked
    through ``motion_allowed``): where it refuses every curved arc (a wall a few millimetres
    away, which the costmap's 5 cm cells do not resolve), the rover drives out straight."""
    _cm, ctrl, start = wedged(cfg)
    asked: list[tuple[float, float]] = []

    def allowed(v: float, w: float) -> bool:
        asked.append((v, w))
        return abs(w) < 1e-9

    ctrl.motion_allowed = allowed
    _pose, log = drive(ctrl, start, 90.0)
    assert asked
    making_room = [o for _, _, o in log if o.detail.endswith("to make room to turn")]
    assert making_room and all(o.angular_radps == 0.0 for o in making_room)
