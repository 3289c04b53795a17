"""The stop zone: the footprint swept along a commanded arc against scan points (``base_link``).

:class:`StopZone` predicts contact of the footprint, moving with a body twist for
``lookahead_s``, with the latest scan's points and says how much of the command may be driven.
Only points the motion *approaches* count, so backing away from, or turning away from, an
obstacle is never blocked. The inner loop is compiled (:mod:`curio.safety.kernel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, arc_poses
from curio.safety.kernel import polygon_distances_into, sweep_stop_zone

__all__ = ["ROVER_CLOSING_MPS", "StopZone", "StopZoneResult", "closing_speeds_mps", "convex_hull",
           "polygon_distances"]

F64 = npt.NDArray[np.float64]

# The rover's own motion bringing its footprint nearer to someone faster than this (m/s) makes a
# contact or a close pass its doing (the simulator's collision fault, the crowd's encounters).
ROVER_CLOSING_MPS = 0.05
CLOSING_DT_S = 0.1


def polygon_distances(points: F64, polygon: F64) -> F64:
    """Signed distance from each point to a polygon's boundary, metres (negative inside).

    Args:
        points: ``(..., 2)`` points in the polygon's frame.
        polygon: ``(E, 2)`` vertices, either orientation.
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = np.ascontiguousarray(pts.reshape(-1, 2))
    out = np.empty(flat.shape[0])
    polygon_distances_into(flat, np.ascontiguousarray(polygon, dtype=np.float64), out)
    shaped: F64 = out.reshape(pts.shape[:-1])
    return shaped


def closing_speeds_mps(footprint: F64, pose: Pose2D, linear_mps: float, angular_radps: float,
                       points: F64) -> F64:
    """How fast the rover's own motion brings its footprint nearer to each point, m/s
    (negative: farther): the distance now less the distance after 0.1 s along the body twist.

    Args:
        footprint: ``(E, 2)`` polygon in ``base_link``, m.
        pose: the rover's pose in ``map``.
        linear_mps: forward speed, m/s.
        angular_radps: yaw rate, rad/s (counter-clockwise positive).
        points: ``(N, 2)`` points in ``map``, m (a body's centre: its radius does not matter).
    """
    ahead = pose @ Pose2D(linear_mps * CLOSING_DT_S, 0.0, angular_radps * CLOSING_DT_S)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    now = polygon_distances(pose.inverse().transform_points(pts), footprint)
    later = polygon_distances(ahead.inverse().transform_points(pts), footprint)
    closing: F64 = (now - later) / CLOSING_DT_S
    return closing


def convex_hull(points: F64) -> F64:
    """Convex hull ``(M, 2)`` of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted({(float(x), float(y)) for x, y in points})
    if len(pts) < 3:
        return np.asarray(pts, dtype=np.float64)

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.asarray(lower[:-1] + upper[:-1], dtype=np.float64)


@dataclass
class StopZoneResult:
    """What the stop zone allows for one command.

    Attributes:
        factor: 0..1 multiplier for both ``v`` and ``ω`` (0 = stop).
        reason: ``""``, ``"slow"`` or ``"stop"``.
        clearance_m: smallest predicted distance between the footprint and an approached point.
        time_to_contact_s: when the margin would be reached at the commanded speed (inf: never).
    """

    factor: float
    reason: str = ""
    clearance_m: float = math.inf
    time_to_contact_s: float = math.inf


class StopZone:
    """Predicts contact of the swept footprint with scan points (all in ``base_link``).

    Args:
        footprint: polygon vertices in ``base_link``, metres.
        stop_distance_m: margin kept around the footprint.
        slow_distance_m: approached points nearer than this slow the rover.
        lookahead_s: how far ahead the commanded arc is swept.
        contact_margin_m: margin for points already inside ``stop_distance_m`` and for pure turns.
        slow_min_fraction: the slowest the slow zone makes the rover (fraction of the command).
        steps: samples along the sweep.
    """

    def __init__(
        self,
        footprint: list[tuple[float, float]],
        stop_distance_m: float,
        slow_distance_m: float,
        lookahead_s: float,
        contact_margin_m: float = 0.02,
        slow_min_fraction: float = 0.4,
        steps: int = 10,
    ) -> None:
        self.footprint = np.asarray(footprint, dtype=np.float64)
        self.stop_distance_m = stop_distance_m
        self.slow_distance_m = max(slow_distance_m, stop_distance_m)
        self.lookahead_s = lookahead_s
        self.contact_margin_m = min(contact_margin_m, stop_distance_m)
        self.slow_min_fraction = slow_min_fraction
        self.steps = steps
        self.radius_m = float(np.max(np.hypot(self.footprint[:, 0], self.footprint[:, 1])))
        self.points: F64 = np.zeros((0, 2))
        self._poly_cache: dict[float, F64] = {}

    def _extended(self, dx_m: float) -> F64:
        """The footprint swept ``dx_m`` along x (its convex hull), the stop or slow polygon."""
        key = round(dx_m, 6)
        poly = self._poly_cache.get(key)
        if poly is None:
            shifted = self.footprint + np.array([dx_m, 0.0])
            poly = convex_hull(np.vstack([self.footprint, shifted]))
            self._poly_cache[key] = poly
        return poly

    def set_points(self, points_base: F64) -> None:
        """Replace the obstacle points ``(N, 2)`` in ``base_link``."""
        self.points = np.asarray(points_base, dtype=np.float64).reshape(-1, 2)

    def evaluate(self, linear_mps: float, angular_radps: float) -> StopZoneResult:
        """How much of the command ``(v, ω)`` the obstacles allow."""
        if self.points.size == 0 or (abs(linear_mps) < 1e-6 and abs(angular_radps) < 1e-6):
            return StopZoneResult(1.0)
        reach = (self.radius_m + self.slow_distance_m + abs(linear_mps) * self.lookahead_s
                 + 0.05)
        dt = self.lookahead_s / self.steps
        times = np.arange(self.steps + 1, dtype=np.float64) * dt
        poses = arc_poses(linear_mps, angular_radps, times)  # (K, 3)
        pure_turn = abs(linear_mps) < 1e-3
        direction = 0.0 if pure_turn else math.copysign(1.0, linear_mps)
        stop_poly = self._extended(direction * self.stop_distance_m)
        use_slow = self.slow_distance_m > self.stop_distance_m and not pure_turn
        slow_poly = self._extended(direction * self.slow_distance_m) if use_slow else stop_poly
        # Compiled sweep (safety_kernel): per point within reach and outside the footprint,
        # its distances to the stop polygon along the arc, reduced to what is decided below.
        approached, clearance, first_hit, slow_near = sweep_stop_zone(
            self.points, reach, poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]),
            self.footprint, stop_poly, slow_poly, use_slow, self.contact_margin_m)
        if not approached:
            return StopZoneResult(1.0)
        factor = 1.0
        reason = ""
        ttc = math.inf
        if first_hit >= 0:  # first step (0-based over times[1:]) reaching the contact margin
            ttc = float(times[first_hit + 1])
            factor = min(1.0, float(times[first_hit]) / self.lookahead_s)
            reason = "stop" if factor <= 0.0 else "slow"
        if slow_near < math.inf:  # an approached point inside the slow polygon
            near = max(0.0, float(slow_near))
            span = self.slow_distance_m - self.stop_distance_m
            slow = min(1.0, max(self.slow_min_fraction, near / span))
            if slow < factor:
                factor = slow
                reason = reason or "slow"
        return StopZoneResult(factor, reason, float(clearance), ttc)
