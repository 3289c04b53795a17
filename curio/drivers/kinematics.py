"""Curio's inverse and forward kinematics (pure; hardware.md §2.2, §2.3).

Frames and units: ``base_link`` (REP-103: x forward, y left, yaw counter-clockwise) at the
midpoint of the two middle wheels; speeds in m/s and rad/s, angles in radians unless the name
says ``deg``.

Inverse kinematics (:func:`twist_to_servo_command`) follows the original base controller
exactly:

* the turning centre (ICC) is at ``(0, r_p)`` with ``r_p = v / ω``; ``ω == 0`` (an exact float
  test) drives straight;
* each wheel at ``(x_i, y_i)`` gets ``v_i = s_i · hypot(x_i, r_p − y_i) · ω`` with ``s_i = −1``
  when ``r_p − y_i < 0``; corner steering ``δ_i = atan2(x_i, r_p − y_i)`` folded into ±90°;
* a limiter scales every wheel speed so the fastest is at most ``max_wheel_speed_mps`` (0.37);
* LX-16A motor duty ``trunc((v_i / R) · o_i · 1000 / 2π)`` with ``o = +1`` left, ``−1`` right;
* LX-16A steering position ``trunc((120 − δ_i[deg]) · 1000 / 240)`` (500 = straight).

Wheel order everywhere: ``FL, ML, BL, FR, MR, BR``; steering order: ``FL, BL, FR, BR``. The
geometry (wheel contact points, radius, the fastest-wheel limit) comes from the robot model
(:class:`curio.robot.RobotModel`). The 0.5 s command timeout is the caller's job (the base
driver / SimBase), not this module's.
"""

from __future__ import annotations

import math

from curio.core.messages import ServoCommand
from curio.robot import RobotModel

__all__ = [
    "DUTY_PER_RADPS",
    "STEER_CORNERS",
    "WHEEL_SIDES",
    "duty_to_servo_radps",
    "forward_kinematics",
    "inverse_kinematics",
    "servo_command_to_twist",
    "steer_angle_to_position",
    "steer_position_to_angle",
    "twist_to_servo_command",
]

# LX-16A motor mode: duty ±1000 ↔ ±2π rad/s (hardware.md §2.3, an assumed mapping constant).
DUTY_PER_RADPS = 1000.0 / (2.0 * math.pi)
# Mounting orientation per wheel (FL, ML, BL, FR, MR, BR): the right servos are mirrored.
WHEEL_SIDES: tuple[int, int, int, int, int, int] = (1, 1, 1, -1, -1, -1)
# Index into the six wheels of each steering corner (FL, BL, FR, BR).
STEER_CORNERS: tuple[int, int, int, int] = (0, 2, 3, 5)
_MAX_TURN_RADIUS_M = 1e6


def inverse_kinematics(
    linear_mps: float, angular_radps: float, robot: RobotModel
) -> tuple[list[float], list[float]]:
    """Wheel ground speeds (m/s, six, after the limiter) and corner angles (rad, four, ±π/2).

    Speeds are signed along each wheel's steered heading, forward positive, before the servo
    orientation is applied.
    """
    geo = robot.wheels
    v, w = float(linear_mps), float(angular_radps)
    if not (math.isfinite(v) and math.isfinite(w)):
        raise ValueError(f"twist must be finite, got linear {v} m/s, angular {w} rad/s")
    speeds = [v] * 6
    angles = [0.0] * 4
    # Exact float test, as the original; a turning radius beyond 1e6 m (a denormal ω) is
    # also straight, so the arithmetic below never overflows to inf/nan.
    if w != 0.0 and abs(v) < _MAX_TURN_RADIUS_M * abs(w):
        r_p = v / w
        for i in range(6):
            dy = r_p - geo.y_m[i]
            sign = -1.0 if dy < 0.0 else 1.0
            speeds[i] = sign * math.hypot(geo.x_m[i], dy) * w
        for k, i in enumerate(STEER_CORNERS):
            delta = math.atan2(geo.x_m[i], r_p - geo.y_m[i])
            if delta > math.pi / 2:
                delta -= math.pi
            elif delta < -math.pi / 2:
                delta += math.pi
            angles[k] = delta
    fastest = max(abs(s) for s in speeds)
    if fastest > robot.max_wheel_speed_mps:
        scale = robot.max_wheel_speed_mps / fastest
        speeds = [s * scale for s in speeds]
    return speeds, angles


def steer_angle_to_position(delta_rad: float) -> int:
    """LX-16A steering position for a corner angle: ``trunc((120 − δ°)·1000/240)``."""
    return int((120.0 - math.degrees(delta_rad)) * 1000.0 / 240.0)


def steer_position_to_angle(position: int | float) -> float:
    """Corner angle (rad) of an LX-16A steering position (inverse of the mapping above)."""
    return math.radians(120.0 - float(position) * 240.0 / 1000.0)


def duty_to_servo_radps(duty: int | float) -> float:
    """Nominal servo shaft speed (rad/s, positive = counts increase) for a motor duty."""
    return float(duty) / DUTY_PER_RADPS


def _clamp_duty(value: int) -> int:
    return max(-1000, min(1000, value))


def twist_to_servo_command(
    linear_mps: float, angular_radps: float, robot: RobotModel, stamp: float
) -> ServoCommand:
    """The servo command for a twist in ``base_link`` (hardware.md §2.2, exactly).

    Args:
        linear_mps: forward speed, m/s.
        angular_radps: yaw rate, rad/s (counter-clockwise positive).
        robot: geometry and the fastest-wheel limit.
        stamp: the command's time, seconds.

    Returns:
        Duties (FL, ML, BL, FR, MR, BR) in −1000..1000 and steering positions (FL, BL, FR, BR).

    Raises:
        ValueError: a non-finite speed.
    """
    speeds, angles = inverse_kinematics(linear_mps, angular_radps, robot)
    radius = robot.wheels.wheel_radius_m
    duties = tuple(
        _clamp_duty(int((s / radius) * o * DUTY_PER_RADPS))
        for s, o in zip(speeds, WHEEL_SIDES, strict=True)
    )
    positions = tuple(steer_angle_to_position(a) for a in angles)
    return ServoCommand(
        stamp=stamp,
        wheel_duty=(duties[0], duties[1], duties[2], duties[3], duties[4], duties[5]),
        steer_position=(positions[0], positions[1], positions[2], positions[3]),
        steer_move_time_ms=50,
    )


def forward_kinematics(
    left_mps: float, right_mps: float, track_m: float
) -> tuple[float, float]:
    """Body twist ``(v m/s, ω rad/s)`` from the mid wheels' ground speeds (differential drive)."""
    return 0.5 * (left_mps + right_mps), (right_mps - left_mps) / track_m


def servo_command_to_twist(cmd: ServoCommand, robot: RobotModel) -> tuple[float, float]:
    """The twist ``(v m/s, ω rad/s)`` a servo command asks for, from its mid-wheel duties.

    Exact up to the duty truncation (the ICC lies on the mid axle), using the nominal radius
    and track of the controller.
    """
    geo = robot.wheels
    left = duty_to_servo_radps(cmd.wheel_duty[1]) * geo.wheel_radius_m * WHEEL_SIDES[1]
    right = duty_to_servo_radps(cmd.wheel_duty[4]) * geo.wheel_radius_m * WHEEL_SIDES[4]
    return forward_kinematics(left, right, geo.mid_track_m)
