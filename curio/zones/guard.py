"""Honouring zones while driving: a speed limit for the controller, a last check for the
safety stage.

:class:`ZoneGuard` holds the zones of the map and the rover's footprint (``base_link``):

* :meth:`ZoneGuard.speed_limit_at` — the lowest limit of the speed zones the footprint at a
  pose in ``map`` is within ``zones.speed_margin_m`` of (so the rover has slowed down before any
  part of it enters), times ``SPEED_MARGIN`` (0.9: the true wheel radius differs from the
  nominal one the base commands with), ``inf`` when none; the local controller caps its target
  speed with it.
* :meth:`ZoneGuard.limit` — for the safety stage: the commanded body twist scaled so that the
  footprint, swept along the commanded arc for ``zones.lookahead_s``, stops short of every
  keep-out zone (the costmap already keeps the planner and the controller out; this is the
  check that holds whatever the source of the command, teleop included), then capped by the
  speed limit. It uses the latest ``/pose``; without one it passes the command unchanged (the
  stop zone and the watchdog still apply). A rover already overlapping a keep-out zone (a zone
  drawn over it) may drive: only entering is prevented.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.config import ZonesConfig
from curio.core.geometry import Pose2D, arc_poses
from curio.core.topics import POSE
from curio.robot import RobotModel

from .geometry import polygon_distance, polygons_overlap
from .model import Zone

__all__ = ["ZoneGuard"]

F64 = npt.NDArray[np.float64]
STEPS = 10
# Speed zones are driven at this share of their limit: the base turns speeds into wheel duties
# with the nominal wheel radius, and the true one differs (robot.wheel_radius_multiplier, and
# each rover's own scale error), so the true speed may be up to ~10 % above the command.
SPEED_MARGIN = 0.9


def _bbox(poly: F64) -> tuple[float, float, float, float]:
    return (float(poly[:, 0].min()), float(poly[:, 1].min()), float(poly[:, 0].max()),
            float(poly[:, 1].max()))


class ZoneGuard:
    """The zones as the controller and the safety stage see them (see the module docstring).

    Args:
        robot: the footprint (``base_link``) and its circumscribed radius.
        cfg: ``[zones]``.
        bus: for the latest ``/pose`` (the safety stage's check).
    """

    def __init__(self, robot: RobotModel, cfg: ZonesConfig, bus: Bus | None = None) -> None:
        self.footprint = np.asarray(robot.footprint, dtype=np.float64)
        self.radius_m = robot.circumscribed_radius_m
        self.cfg = cfg
        self.bus = bus
        self.keepouts: list[tuple[F64, tuple[float, float, float, float]]] = []
        self.speeds: list[tuple[F64, tuple[float, float, float, float], float]] = []
        self.interventions = 0

    def set_zones(self, zones: list[Zone]) -> None:
        """Take the zones of the map (replaces the previous ones)."""
        self.keepouts = [(z.vertices(), _bbox(z.vertices())) for z in zones
                         if z.kind == "keepout"]
        self.speeds = [(z.vertices(), _bbox(z.vertices()), float(z.speed_limit_mps))
                       for z in zones if z.kind == "speed" and z.speed_limit_mps is not None]

    def footprint_at(self, pose: Pose2D) -> F64:
        """The footprint polygon at ``pose`` in ``map``."""
        return pose.transform_points(self.footprint)

    @staticmethod
    def _near(pose: Pose2D, box: tuple[float, float, float, float], reach: float) -> bool:
        return (box[0] - reach <= pose.x <= box[2] + reach
                and box[1] - reach <= pose.y <= box[3] + reach)

    def speed_limit_at(self, pose: Pose2D) -> float:
        """The speed limit for a rover at ``pose`` (``map``), m/s; ``inf`` when none."""
        limit = math.inf
        margin = self.cfg.speed_margin_m
        fp: F64 | None = None
        for poly, box, mps in self.speeds:
            if mps >= limit or not self._near(pose, box, self.radius_m + margin):
                continue
            fp = self.footprint_at(pose) if fp is None else fp
            if polygon_distance(fp, poly) <= margin:
                limit = mps
        return limit * SPEED_MARGIN if math.isfinite(limit) else limit

    def in_keepout(self, pose: Pose2D) -> bool:
        """Whether the footprint at ``pose`` overlaps a keep-out zone."""
        fp: F64 | None = None
        for poly, box in self.keepouts:
            if self._near(pose, box, self.radius_m):
                fp = self.footprint_at(pose) if fp is None else fp
                if polygons_overlap(fp, poly):
                    return True
        return False

    def keepout_factor(self, pose: Pose2D, linear_mps: float, angular_radps: float) -> float:
        """How much of ``(v, ω)`` keeps the swept footprint out of keep-out zones (0..1)."""
        if not self.keepouts or (abs(linear_mps) < 1e-6 and abs(angular_radps) < 1e-6):
            return 1.0
        reach = self.radius_m + abs(linear_mps) * self.cfg.lookahead_s
        near = [(poly, box) for poly, box in self.keepouts if self._near(pose, box, reach)]
        if not near or self.in_keepout(pose):
            return 1.0
        times = np.arange(1, STEPS + 1, dtype=np.float64) * (self.cfg.lookahead_s / STEPS)
        for k, (dx, dy, dth) in enumerate(arc_poses(linear_mps, angular_radps, times)):
            fp = self.footprint_at(pose @ Pose2D(float(dx), float(dy), float(dth)))
            if any(polygons_overlap(fp, poly) for poly, _ in near):
                return k / STEPS
        return 1.0

    def limit(self, linear_mps: float, angular_radps: float) -> tuple[float, float]:
        """The safety stage's check: ``(v, ω)`` scaled for keep-out zones and capped by the
        speed limit at the latest ``/pose`` (unchanged without a pose)."""
        if self.bus is None or not (self.keepouts or self.speeds):
            return linear_mps, angular_radps
        msg = self.bus.latest(POSE)
        if msg is None:
            return linear_mps, angular_radps
        v, w = linear_mps, angular_radps
        factor = self.keepout_factor(msg.pose, v, w)
        if factor < 1.0:
            v, w = v * factor, w * factor
        limit = self.speed_limit_at(msg.pose)
        if abs(v) > limit:
            k = limit / abs(v)
            v, w = v * k, w * k
        if (v, w) != (linear_mps, angular_radps):
            self.interventions += 1
        return v, w
