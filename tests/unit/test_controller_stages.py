"""The local controller's stages as functions: frames, lookahead, hysteresis, pursuit, speed."""

from __future__ import annotations

import math

import pytest

from curio.core.config import Config, ControllerConfig, RobotConfig
from curio.core.geometry import Pose2D
from curio.nav.controller import (
    lookahead_m,
    pursuit_curvature,
    regulated_speed,
    rotate_hysteresis,
    to_base_link,
)
from curio.robot import RobotModel

CFG = ControllerConfig()  # lookahead 0.6 (min 0.35, narrow 0.3); rotate 0.8 / 0.25 (narrow 0.45)


def test_to_base_link() -> None:
    x, y = to_base_link(Pose2D(1.0, 2.0, math.pi / 2), 1.0, 3.0)  # 1 m ahead
    assert (x, y) == pytest.approx((1.0, 0.0))
    x, y = to_base_link(Pose2D(1.0, 2.0, math.pi / 2), 0.0, 2.0)  # 1 m to the right... of x
    assert (x, y) == pytest.approx((0.0, 1.0))


def test_lookahead_between_the_minimum_and_the_goal() -> None:
    assert lookahead_m(CFG, 5.0, False) == (0.6, 0.8)
    assert lookahead_m(CFG, 0.5, False) == (0.5, 0.8)  # no farther than the goal
    assert lookahead_m(CFG, 0.1, False) == (0.35, 0.8)  # never nearer than the minimum


def test_lookahead_before_a_narrow_passage() -> None:
    assert lookahead_m(CFG, 5.0, True) == (0.3, 0.45)
    assert lookahead_m(CFG, 0.1, True) == (0.3, 0.45)


@pytest.mark.parametrize(("rotating", "err", "expected"), [
    (False, 0.79, False), (False, 0.81, True), (False, -0.81, True),  # enter above 0.8
    (True, 0.26, True), (True, 0.24, False), (True, -0.26, True),  # leave below 0.25
])
def test_rotate_hysteresis(rotating: bool, err: float, expected: bool) -> None:
    assert rotate_hysteresis(rotating, err, 0.8, 0.25) is expected


def test_rotate_hysteresis_never_enters_below_the_exit_threshold() -> None:
    assert rotate_hysteresis(False, 0.2, 0.1, 0.25) is False
    assert rotate_hysteresis(False, 0.3, 0.1, 0.25) is True


def test_pursuit_curvature() -> None:
    assert pursuit_curvature(1.0, 0.0, 2.0) == 0.0
    assert pursuit_curvature(0.6, 0.3, 9.0) == pytest.approx(2 * 0.3 / 0.45)
    assert pursuit_curvature(0.0, 0.5, 2.0) == 2.0  # clamped to the tightest arc
    assert pursuit_curvature(0.0, -0.5, 2.0) == -2.0
    assert pursuit_curvature(0.0, 0.0, 2.0) == 0.0  # on the point: straight


@pytest.fixture
def robot(cfg: Config) -> RobotModel:
    return RobotModel.from_config(cfg.robot)


def test_regulated_speed_straight_and_free(robot: RobotModel) -> None:
    assert regulated_speed(CFG, robot, 0.0, math.inf, 5.0, False) == (CFG.max_speed_mps, "")


def test_regulated_speed_on_an_arc(robot: RobotModel) -> None:
    v, detail = regulated_speed(CFG, robot, 2.0, math.inf, 5.0, False)
    assert v == pytest.approx(min(robot.max_speed_on_arc_mps(2.0), CFG.max_angular_radps / 2.0))
    assert v < CFG.max_speed_mps and detail == ""
    slow = CFG.model_copy(update={"max_angular_radps": 0.2})
    assert regulated_speed(slow, robot, 2.0, math.inf, 5.0, False)[0] == pytest.approx(0.1)


def test_regulated_speed_near_an_obstacle() -> None:
    robot = RobotModel.from_config(RobotConfig())
    v, detail = regulated_speed(CFG, robot, 0.0, 0.12, 5.0, False)  # 0.12 of 0.15: 80 %
    assert v == pytest.approx(0.8 * CFG.max_speed_mps) and detail == "near an obstacle"
    v, _ = regulated_speed(CFG, robot, 0.0, 0.0, 5.0, False)  # never below 60 %
    assert v == pytest.approx(0.6 * CFG.max_speed_mps)
    assert regulated_speed(CFG, robot, 0.0, 0.16, 5.0, False)[1] == ""


def test_regulated_speed_approaching_the_goal() -> None:
    robot = RobotModel.from_config(RobotConfig())
    # sqrt(2 · 0.3 · (0.1 − 0.075)) ≈ 0.12 m/s
    v, detail = regulated_speed(CFG, robot, 0.0, math.inf, 0.1, False)
    assert v == pytest.approx(math.sqrt(2 * 0.3 * 0.025)) and detail == "approaching the goal"
    v, _ = regulated_speed(CFG, robot, 0.0, math.inf, 0.07, False)
    assert v == CFG.min_speed_mps  # never below the minimum
    v, detail = regulated_speed(CFG, robot, 0.0, 0.0, 0.1, False)
    assert detail == "near an obstacle"  # the first reason is kept


def test_regulated_speed_while_the_servos_settle() -> None:
    robot = RobotModel.from_config(RobotConfig())
    assert regulated_speed(CFG, robot, 0.0, 0.0, 0.1, True) == (0.0, "steering servos settling")
