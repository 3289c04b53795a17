"""The robot model: Curio's geometry and limits, built once from ``[robot]`` in the config.

Every part that needs a fact about the rover's body takes this model instead of computing it:
the kinematics and the bases (wheel positions), the safety stage (footprint, wheel-speed
limit, laser pose), the controller (footprint, fastest-wheel speed on an arc), the costmap
(footprint and its radii), the estimators (laser and IMU poses), the simulator and the
dashboard. A changed ``robot.*`` key in ``config.toml`` therefore changes all of them at once.

Frames and units: ``base_link`` (REP-103: x forward, y left, yaw counter-clockwise) at the
midpoint of the two middle wheels (hardware.md §2.1); metres, radians, m/s, rad/s. Wheel order
everywhere: ``FL, ML, BL, FR, MR, BR``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.config import RobotConfig
from curio.core.geometry import Pose2D

__all__ = ["RobotModel", "WheelGeometry", "footprint_radii", "pad_footprint"]

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class WheelGeometry:
    """Wheel contact points in ``base_link`` (metres), order FL, ML, BL, FR, MR, BR."""

    x_m: tuple[float, float, float, float, float, float]
    y_m: tuple[float, float, float, float, float, float]
    wheel_radius_m: float

    @property
    def positions_m(self) -> tuple[tuple[float, float], ...]:
        """The six ``(x, y)`` contact points."""
        return tuple(zip(self.x_m, self.y_m, strict=True))

    @property
    def mid_track_m(self) -> float:
        """Lateral distance between the two middle wheels, metres."""
        return self.y_m[1] - self.y_m[4]


def pad_footprint(footprint: F64 | list[tuple[float, float]], padding_m: float) -> F64:
    """Grow a footprint polygon by ``padding_m`` (each vertex moved outwards per axis, as Nav2).

    Returns an ``(N, 2)`` array in ``base_link``, metres.
    """
    poly = np.asarray(footprint, dtype=np.float64).reshape(-1, 2)
    padded: F64 = poly + np.sign(poly) * padding_m
    return padded


def footprint_radii(polygon: F64) -> tuple[float, float]:
    """Return ``(inscribed, circumscribed)`` radii of a polygon about ``base_link``'s origin, m.

    The inscribed radius is the smallest distance from the origin to an edge; the
    circumscribed radius the largest distance to a vertex.
    """
    a = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    denom = np.maximum((ab * ab).sum(axis=1), 1e-12)
    t = np.clip(((-a) * ab).sum(axis=1) / denom, 0.0, 1.0)
    closest = a + t[:, None] * ab
    inscribed = float(np.min(np.hypot(closest[:, 0], closest[:, 1])))
    circumscribed = float(np.max(np.hypot(a[:, 0], a[:, 1])))
    return inscribed, circumscribed


@dataclass(frozen=True)
class RobotModel:
    """Curio's body: footprint, wheels, sensor mounts, home and speed limits.

    Attributes:
        footprint: ``(N, 2)`` polygon in ``base_link``, metres (read-only).
        inscribed_radius_m: smallest distance from ``base_link`` to the footprint's edge.
        circumscribed_radius_m: largest distance from ``base_link`` to a footprint vertex.
        wheels: the controller's nominal wheel contact points and radius.
        laser_in_base: the ``laser`` frame in ``base_link``.
        imu_in_base: the ``imu_link`` frame in ``base_link``.
        home: the home pose in ``map``.
        max_wheel_speed_mps: the fastest any wheel may turn, ground speed.
        max_angular_radps: the body's yaw-rate limit.
        odom_wheel_radius_m: the calibrated wheel radius for odometry (nominal × multiplier).
        odom_track_m: the calibrated mid-wheel track for odometry (nominal × multiplier).
    """

    footprint: F64
    inscribed_radius_m: float
    circumscribed_radius_m: float
    wheels: WheelGeometry
    laser_in_base: Pose2D
    imu_in_base: Pose2D
    home: Pose2D
    max_wheel_speed_mps: float
    max_angular_radps: float
    odom_wheel_radius_m: float
    odom_track_m: float

    @classmethod
    def from_config(cls, cfg: RobotConfig) -> RobotModel:
        """Build the model from ``[robot]``."""
        footprint = np.asarray(cfg.footprint, dtype=np.float64).reshape(-1, 2)
        footprint.setflags(write=False)
        inscribed, circumscribed = footprint_radii(footprint)
        return cls(
            footprint=footprint,
            inscribed_radius_m=inscribed,
            circumscribed_radius_m=circumscribed,
            wheels=wheel_geometry(cfg),
            laser_in_base=Pose2D(*cfg.laser_pose),
            imu_in_base=Pose2D(*cfg.imu_pose),
            home=Pose2D(*cfg.home),
            max_wheel_speed_mps=cfg.max_wheel_speed_mps,
            max_angular_radps=cfg.max_angular_radps,
            odom_wheel_radius_m=cfg.wheel_radius_m * cfg.wheel_radius_multiplier,
            odom_track_m=cfg.mid_wheel_track_m * cfg.mid_wheel_track_multiplier,
        )

    @property
    def footprint_points(self) -> list[tuple[float, float]]:
        """The footprint as a list of ``(x, y)`` vertices (metres, ``base_link``)."""
        return [(float(x), float(y)) for x, y in self.footprint]

    def padded_footprint(self, padding_m: float) -> F64:
        """The footprint grown by ``padding_m`` (see :func:`pad_footprint`)."""
        return pad_footprint(self.footprint, padding_m)

    def fastest_wheel_speed_mps(self, linear_mps: float, angular_radps: float) -> float:
        """Ground speed of the fastest wheel for a body twist, m/s.

        Wheel ``i`` at ``(x, y)`` moves at ``|ω| · hypot(x, r − y)`` with ``r = v / ω``, i.e.
        ``hypot(x·ω, v − y·ω)`` (hardware.md §2.2); for ``ω = 0`` every wheel moves at
        ``|v|``.
        """
        return max(math.hypot(x * angular_radps, linear_mps - y * angular_radps)
                   for x, y in self.wheels.positions_m)

    def limit_to_wheel_speed(self, linear_mps: float, angular_radps: float,
                             max_wheel_speed_mps: float | None = None) -> tuple[float, float]:
        """Scale ``(v, ω)`` together so no wheel exceeds the limit (keeps the turning radius).

        Args:
            linear_mps, angular_radps: the wanted body twist in ``base_link``.
            max_wheel_speed_mps: the limit; default the robot's ``max_wheel_speed_mps``.
        """
        limit = self.max_wheel_speed_mps if max_wheel_speed_mps is None else max_wheel_speed_mps
        fastest = self.fastest_wheel_speed_mps(linear_mps, angular_radps)
        if fastest <= limit or fastest <= 0.0:
            return linear_mps, angular_radps
        k = limit / fastest
        return linear_mps * k, angular_radps * k

    def max_speed_on_arc_mps(self, curvature_per_m: float) -> float:
        """The fastest forward speed (m/s) on an arc of curvature ``κ`` (1/m) that keeps every
        wheel within ``max_wheel_speed_mps``."""
        per_unit = self.fastest_wheel_speed_mps(1.0, curvature_per_m)
        return self.max_wheel_speed_mps / per_unit if per_unit > 0.0 else math.inf


def wheel_geometry(robot: RobotConfig, lateral_scale: float = 1.0) -> WheelGeometry:
    """The wheel contact points from the config (hardware.md §2.1 table).

    Args:
        robot: ``[robot]``.
        lateral_scale: multiplies every y (the simulator uses the track multiplier to model
            rocker-bogie flex); 1.0 gives the controller's nominal geometry.
    """
    xf, xb = robot.front_wheel_lon_m, -robot.back_wheel_lon_m
    yc = 0.5 * robot.corner_wheel_track_m * lateral_scale
    ym = 0.5 * robot.mid_wheel_track_m * lateral_scale
    return WheelGeometry(
        x_m=(xf, 0.0, xb, xf, 0.0, xb),
        y_m=(yc, ym, yc, -yc, -ym, -yc),
        wheel_radius_m=robot.wheel_radius_m,
    )
