"""The dock's shape: what the lidar looks for and what the simulator builds.

Dock frame: the origin is the **docked pose** of ``base_link`` (home), x points into the dock
(the rover's heading when docked), y to the left (REP-103), metres. The dock stands in front of
the docked rover: its face is a plate ``face_x_m`` ahead of the origin (the rover's front plus
a ``FRONT_GAP_M`` gap the charging contacts bridge), ``2 · WING_HALF_M`` wide, with a V-shaped
notch ``2 · NOTCH_HALF_M`` wide and ``NOTCH_DEPTH_M`` deep in its middle:

::

       y ↑   face ──────┐
             +0.40 ─────┤        wing
             +0.15 ─────┤╲       notch side
                        │  ╲ apex (face + 0.12, 0)
             −0.15 ─────┤╱
             −0.40 ─────┘        wing
                        x → (into the dock)

The flat wings fix the distance and the heading, the notch the lateral offset: fitted to the
scan points (:mod:`curio.docking.perception`) they give the dock's pose to a few millimetres
from a metre away, without the map. In the simulator (:class:`DockStation`) the dock is two
convex blocks (its outline blocks rays and the rover) and a charging contact that touches when
the rover is within ``dock.contact_xy_m`` and ``dock.contact_yaw_rad`` of the docked pose.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, wrap_angle
from curio.estimation.maps import OccupancyGrid

__all__ = ["FRONT_GAP_M", "DockShape", "DockStation", "stamp_dock"]

F64 = npt.NDArray[np.float64]

FRONT_GAP_M = 0.02
WING_HALF_M = 0.40
NOTCH_HALF_M = 0.15
NOTCH_DEPTH_M = 0.12
BODY_DEPTH_M = 0.20


@dataclass(frozen=True)
class DockShape:
    """The dock's geometry in the dock frame (see the module docstring).

    Attributes:
        face_x_m: the face plate's distance ahead of the docked ``base_link``.
    """

    face_x_m: float

    @classmethod
    def for_footprint(cls, footprint: F64 | list[tuple[float, float]]) -> DockShape:
        """The dock for a rover with this footprint (``base_link``): its face
        ``FRONT_GAP_M`` ahead of the footprint's front."""
        front = float(np.max(np.asarray(footprint, dtype=np.float64)[:, 0]))
        return cls(front + FRONT_GAP_M)

    def profile(self) -> F64:
        """The face's outline the lidar sees: ``(4, 4)`` segments ``x1, y1, x2, y2``."""
        f = self.face_x_m
        apex = (f + NOTCH_DEPTH_M, 0.0)
        return np.array([
            (f, WING_HALF_M, f, NOTCH_HALF_M),
            (f, NOTCH_HALF_M, *apex),
            (*apex, f, -NOTCH_HALF_M),
            (f, -NOTCH_HALF_M, f, -WING_HALF_M),
        ], dtype=np.float64)

    def blocks(self) -> list[F64]:
        """The solid dock as two convex polygons (left and right of the notch's axis)."""
        f, b = self.face_x_m, self.face_x_m + BODY_DEPTH_M
        apex = f + NOTCH_DEPTH_M
        left = np.array([(f, NOTCH_HALF_M), (apex, 0.0), (b, 0.0), (b, WING_HALF_M),
                         (f, WING_HALF_M)])
        right = left * np.array([1.0, -1.0])
        return [left, right[::-1].copy()]


@dataclass
class DockStation:
    """A dock in the simulated world.

    Args:
        pose: the docked pose of ``base_link`` in ``map`` (home).
        shape: its geometry.
        contact_xy_m, contact_yaw_rad: the charging contact touches within these of the
            docked pose.
        charger_v: the voltage at the contacts while they touch.
    """

    pose: Pose2D
    shape: DockShape
    contact_xy_m: float = 0.02
    contact_yaw_rad: float = 0.05
    charger_v: float = 9.0

    def polygons(self) -> list[list[tuple[float, float]]]:
        """The blocks in ``map`` (for collisions)."""
        return [[(float(x), float(y)) for x, y in self.pose.transform_points(b)]
                for b in self.shape.blocks()]

    def segments(self) -> list[tuple[float, float, float, float]]:
        """The outline in ``map`` (for ray casting)."""
        out: list[tuple[float, float, float, float]] = []
        for poly in self.polygons():
            n = len(poly)
            out.extend((*poly[i], *poly[(i + 1) % n]) for i in range(n))
        return out

    @property
    def centre(self) -> tuple[float, float]:
        """Middle of the dock's body in ``map``."""
        return self.pose.transform_point(self.shape.face_x_m + 0.5 * BODY_DEPTH_M, 0.0)

    @property
    def radius_m(self) -> float:
        """A circle around :attr:`centre` that holds the dock."""
        return math.hypot(0.5 * BODY_DEPTH_M, WING_HALF_M)

    def error(self, rover: Pose2D) -> tuple[float, float, float]:
        """The rover's pose relative to the docked pose: along (m, + = too far in), across (m)
        and heading (rad)."""
        rel = rover.relative_to(self.pose)
        return rel.x, rel.y, wrap_angle(rel.yaw)

    def touching(self, rover: Pose2D) -> bool:
        """Whether the charging contact touches the rover at ``rover`` (``map``)."""
        dx, dy, dyaw = self.error(rover)
        return math.hypot(dx, dy) <= self.contact_xy_m and abs(dyaw) <= self.contact_yaw_rad


def stamp_dock(grid: OccupancyGrid, pose: Pose2D, shape: DockShape) -> OccupancyGrid:
    """``grid`` (an :class:`~curio.estimation.maps.OccupancyGrid`) with the dock at ``pose``
    (the docked pose in ``map``) drawn as occupied cells: the dock stands at home for good, so
    it belongs in the map the localiser matches scans against (docked, it fills a third of the
    lidar's view) and in the costmap's static layer. A map made with the dock in place already
    shows it (``dock.in_map``)."""
    data = np.array(grid.data, copy=True)
    h, w = data.shape
    inv = grid.origin.inverse()
    res = grid.resolution_m
    for block in shape.blocks():
        poly = inv.transform_points(pose.transform_points(block)) / res
        c0, c1 = int(np.floor(poly[:, 0].min())), int(np.ceil(poly[:, 0].max()))
        r0, r1 = int(np.floor(poly[:, 1].min())), int(np.ceil(poly[:, 1].max()))
        for r in range(max(0, r0), min(h, r1 + 1)):
            for c in range(max(0, c0), min(w, c1 + 1)):
                if _inside(c + 0.5, r + 0.5, poly):
                    data[r, c] = 100
    return dataclasses.replace(grid, data=data)


def _inside(x: float, y: float, poly: F64) -> bool:
    inside = False
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside
