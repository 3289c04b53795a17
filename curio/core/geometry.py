"""Planar geometry: SE(2) poses, angle wrapping, yaw ↔ quaternion conversion, constant-twist
arcs and a per-step rate limit.

Conventions (REP-103): metres and radians, x forward, y left, yaw counter-clockwise from +x.
Quaternions are stored in ROS order ``(x, y, z, w)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "Pose2D",
    "angle_diff",
    "approach",
    "arc_poses",
    "quat_to_yaw",
    "wrap_angle",
    "wrap_angles",
    "yaw_to_quat",
]


def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to [-π, π)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def wrap_angles(angles_rad: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Wrap an array of angles to [-π, π)."""
    return np.asarray((angles_rad + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def angle_diff(a_rad: float, b_rad: float) -> float:
    """Return ``a - b`` wrapped to [-π, π)."""
    return wrap_angle(a_rad - b_rad)


def approach(current: float, target: float, max_step: float) -> float:
    """Move ``current`` towards ``target`` by at most ``max_step`` (a per-cycle rate limit)."""
    if target > current + max_step:
        return current + max_step
    if target < current - max_step:
        return current - max_step
    return target


def arc_poses(linear_mps: float, angular_radps: float,
              times_s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Poses ``(K, 3)`` (x, y, yaw) in the start's frame reached by holding a body twist
    (``linear_mps`` forward, ``angular_radps`` counter-clockwise) for each of ``times_s``."""
    th = angular_radps * times_s
    if abs(angular_radps) < 1e-6:
        x = linear_mps * times_s
        y = np.zeros_like(times_s)
    else:
        r = linear_mps / angular_radps
        x = r * np.sin(th)
        y = r * (1.0 - np.cos(th))
    return np.stack([x, y, th], axis=-1)


def yaw_to_quat(yaw_rad: float) -> tuple[float, float, float, float]:
    """Return the quaternion ``(x, y, z, w)`` of a rotation by ``yaw_rad`` about +z."""
    half = 0.5 * yaw_rad
    return (0.0, 0.0, math.sin(half), math.cos(half))


def quat_to_yaw(q_xyzw: tuple[float, float, float, float]) -> float:
    """Return the yaw (rotation about +z, radians) of a quaternion ``(x, y, z, w)``."""
    x, y, z, w = q_xyzw
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@dataclass(frozen=True, slots=True)
class Pose2D:
    """A pose (or transform) in SE(2): position in metres, heading in radians.

    ``a @ b`` composes transforms: if ``a`` is the pose of frame B in frame A and ``b`` the pose
    of C in B, then ``a @ b`` is the pose of C in A.
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    def __matmul__(self, other: Pose2D) -> Pose2D:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return Pose2D(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            wrap_angle(self.yaw + other.yaw),
        )

    def inverse(self) -> Pose2D:
        """Return the inverse transform."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return Pose2D(-c * self.x - s * self.y, s * self.x - c * self.y, wrap_angle(-self.yaw))

    def transform_point(self, x: float, y: float) -> tuple[float, float]:
        """Map a point given in this pose's frame into the parent frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return (self.x + c * x - s * y, self.y + s * x + c * y)

    def transform_points(self, xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Map an ``(N, 2)`` array of points from this pose's frame into the parent frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rot = np.array([[c, -s], [s, c]])
        out: npt.NDArray[np.float64] = np.asarray(xy, dtype=np.float64) @ rot.T + np.array(
            [self.x, self.y])
        return out

    def distance_to(self, other: Pose2D) -> float:
        """Euclidean distance between the two positions, metres."""
        return math.hypot(other.x - self.x, other.y - self.y)

    def relative_to(self, frame: Pose2D) -> Pose2D:
        """Express this pose in ``frame`` (``frame.inverse() @ self``)."""
        return frame.inverse() @ self

    def as_tuple(self) -> tuple[float, float, float]:
        """Return ``(x, y, yaw)``."""
        return (self.x, self.y, self.yaw)
