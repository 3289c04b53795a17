"""SE(2) maths, angle wrapping and yaw/quaternion conversion."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from curio.core.geometry import (
    Pose2D,
    angle_diff,
    quat_to_yaw,
    wrap_angle,
    wrap_angles,
    yaw_to_quat,
)

coords = st.floats(-100, 100, allow_nan=False)
angles = st.floats(-20, 20, allow_nan=False)
poses = st.builds(Pose2D, coords, coords, angles)


def test_wrap_angle_examples() -> None:
    assert wrap_angle(0.0) == 0.0
    assert wrap_angle(math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-7.0) == pytest.approx(-7.0 + 2 * math.pi)
    assert angle_diff(math.radians(179), math.radians(-179)) == pytest.approx(math.radians(-2))
    assert wrap_angles(np.array([4.0, -4.0])) == pytest.approx([4 - 2 * math.pi, 2 * math.pi - 4])


@given(angles)
def test_wrap_is_in_range_and_equivalent(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi <= w < math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9)
    assert math.sin(w) == pytest.approx(math.sin(a), abs=1e-9)


def test_quaternion_convention_is_xyzw() -> None:
    q = yaw_to_quat(math.pi / 2)
    assert q == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert quat_to_yaw((0.0, 0.0, 0.0, 1.0)) == 0.0


@given(angles)
def test_yaw_quaternion_round_trip(a: float) -> None:
    assert wrap_angle(quat_to_yaw(yaw_to_quat(a)) - a) == pytest.approx(0.0, abs=1e-9)


def test_compose_by_hand() -> None:
    robot_in_map = Pose2D(1.0, 2.0, math.pi / 2)
    laser_in_robot = Pose2D(0.152, 0.078, 0.0)
    laser_in_map = robot_in_map @ laser_in_robot
    assert laser_in_map.x == pytest.approx(1.0 - 0.078)
    assert laser_in_map.y == pytest.approx(2.0 + 0.152)
    assert laser_in_map.yaw == pytest.approx(math.pi / 2)
    assert robot_in_map.transform_point(1.0, 0.0) == pytest.approx((1.0, 3.0))


@given(poses, poses)
def test_inverse_and_relative(a: Pose2D, b: Pose2D) -> None:
    ident = a @ a.inverse()
    assert (ident.x, ident.y, ident.yaw) == pytest.approx((0, 0, 0), abs=1e-6)
    rel = b.relative_to(a)
    back = a @ rel
    assert (back.x, back.y) == pytest.approx((b.x, b.y), abs=1e-6)
    assert wrap_angle(back.yaw - b.yaw) == pytest.approx(0.0, abs=1e-9)


@given(poses)
def test_vectorised_transform_matches_scalar(p: Pose2D) -> None:
    pts = np.array([[1.0, 0.0], [0.0, 2.0], [-3.0, 4.0]])
    out = p.transform_points(pts)
    for (x, y), (ox, oy) in zip(pts, out, strict=True):
        assert p.transform_point(x, y) == pytest.approx((ox, oy), abs=1e-9)
