"""Kinematics against the test vectors of hardware.md §2.2 and property tests."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curio.core.config import RobotConfig
from curio.drivers.kinematics import (
    forward_kinematics,
    inverse_kinematics,
    servo_command_to_twist,
    steer_angle_to_position,
    steer_position_to_angle,
    twist_to_servo_command,
)
from curio.robot import RobotModel

ROBOT = RobotModel.from_config(RobotConfig())

# (v, ω) -> corner angles in degrees (FL, BL, FR, BR), positions, duties (FL, ML, BL, FR, MR, BR)
VECTORS = [
    ((0.2, 0.0), (0.0, 0.0, 0.0, 0.0), (500, 500, 500, 500),
     (530, 530, 530, -530, -530, -530)),
    ((0.37, 0.0), (0.0, 0.0, 0.0, 0.0), (500, 500, 500, 500),
     (981, 981, 981, -981, -981, -981)),
    ((0.2, 0.5), (59.49, -56.58, 23.79, -21.49), (252, 735, 400, 589),
     (431, 185, 397, -920, -875, -905)),
    ((0.2, -0.5), (-23.79, 21.49, -59.49, 56.58), (599, 410, 747, 264),
     (920, 875, 905, -431, -185, -397)),
    ((0.0, 1.0), (-49.99, 46.77, 49.99, -46.77), (708, 305, 291, 694),
     (-969, -689, -910, -969, -689, -910)),
    ((0.0, 1.45), (-49.99, 46.77, 49.99, -46.77), (708, 305, 291, 694),
     (-981, -698, -921, -981, -698, -921)),
    ((0.1, 0.5), (-82.87, 82.03, 32.77, -29.89), (845, 158, 363, 624),
     (-374, -79, -334, -686, -610, -665)),
]


@pytest.mark.parametrize(("twist", "angles_deg", "positions", "duties"), VECTORS)
def test_hardware_vectors(
    twist: tuple[float, float],
    angles_deg: tuple[float, ...],
    positions: tuple[int, ...],
    duties: tuple[int, ...],
) -> None:
    _, angles = inverse_kinematics(twist[0], twist[1], ROBOT)
    assert [math.degrees(a) for a in angles] == pytest.approx(angles_deg, abs=0.01)
    cmd = twist_to_servo_command(twist[0], twist[1], ROBOT, stamp=3.5)
    assert cmd.steer_position == positions
    assert cmd.wheel_duty == duties
    assert cmd.stamp == 3.5
    assert cmd.steer_move_time_ms == 50


def test_position_mapping_ends() -> None:
    assert steer_angle_to_position(0.0) == 500
    assert steer_angle_to_position(math.pi / 2) == 125
    assert steer_angle_to_position(-math.pi / 2) == 875
    assert steer_position_to_angle(500) == pytest.approx(0.0)
    assert steer_position_to_angle(125) == pytest.approx(math.pi / 2)


def test_in_place_turn_all_duties_same_sign() -> None:
    for w in (0.3, 1.0, -0.7):
        cmd = twist_to_servo_command(0.0, w, ROBOT, 0.0)
        signs = {d > 0 for d in cmd.wheel_duty}
        assert len(signs) == 1


def test_limiter_starts_at_1012_radps() -> None:
    speeds_below, _ = inverse_kinematics(0.0, 1.0, ROBOT)
    assert max(abs(s) for s in speeds_below) == pytest.approx(0.3655, abs=1e-4)
    speeds_above, _ = inverse_kinematics(0.0, 1.2, ROBOT)
    assert max(abs(s) for s in speeds_above) == pytest.approx(0.37)


def test_non_finite_rejected() -> None:
    with pytest.raises(ValueError, match="finite"):
        twist_to_servo_command(float("nan"), 0.0, ROBOT, 0.0)


@settings(max_examples=200, deadline=None)
@given(v=st.floats(-0.5, 0.5), w=st.floats(-2.0, 2.0))
def test_properties(v: float, w: float) -> None:
    speeds, angles = inverse_kinematics(v, w, ROBOT)
    # Fastest wheel never above the limit, corners within ±90°.
    assert max(abs(s) for s in speeds) <= ROBOT.max_wheel_speed_mps + 1e-12
    assert all(abs(a) <= math.pi / 2 + 1e-12 for a in angles)
    cmd = twist_to_servo_command(v, w, ROBOT, 0.0)
    assert all(-1000 <= d <= 1000 for d in cmd.wheel_duty)
    assert all(125 <= p <= 875 for p in cmd.steer_position)
    # Mid wheels are exactly differential drive: forward kinematics recovers the (limited)
    # twist, and the limiter preserves the turning radius.
    fv, fw = forward_kinematics(speeds[1], speeds[4], ROBOT.wheels.mid_track_m)
    if w != 0.0 and abs(v) < 1e6 * abs(w):  # radii beyond 1e6 m drive straight (by design)
        scale = min(1.0, ROBOT.max_wheel_speed_mps / max(
            abs(s) for s in inverse_kinematics(v, w,
                                               RobotModel.from_config(RobotConfig(max_wheel_speed_mps=2.0)))[0]))
        assert fv == pytest.approx(v * scale, abs=1e-9)
        assert fw == pytest.approx(w * scale, abs=1e-9)
    # The duties decode back to about the same twist (truncation costs < 1 duty unit).
    dv, dw = servo_command_to_twist(cmd, ROBOT)
    assert dv == pytest.approx(fv, abs=0.0004)
    assert dw == pytest.approx(fw, abs=0.002)
