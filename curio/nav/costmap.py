"""Layered costmap in ``map``: static layer, obstacle layer (marking + ray-trace clearing),
footprint inflation, and a rolling local window (Nav2 ``costmap_2d`` semantics).

Costs are ``uint8`` on the static map's grid (same shape, resolution and origin; row 0 at the
bottom, as :class:`~curio.estimation.maps.OccupancyGrid`), with the values and the inflation
formula of :mod:`curio.nav.costs`. The inscribed radius is the robot model's footprint
(``robot.footprint``) grown by ``footprint_padding_m``. Unknown static cells stay
``NO_INFORMATION`` until a laser ray sees them (then they are free) or inflation raises them to
``INSCRIBED`` or more (Nav2's rule with ``inflate_unknown`` false). The map's edge (its
outermost ring of cells) is a wall of the static layer: a footprint cannot leave the grid, so
plans and goals keep off the rim of a map drawn without border walls.

Scans mark their returns within ``obstacle_range_m`` and clear every cell a ray passes
through up to ``raytrace_range_m`` (``inf`` returns clear the full ray range). A return that
lands within ``static_mark_tolerance_cells`` of a mapped wall is taken as that wall (lidar
noise, a slightly offset map) and marks nothing: otherwise noise flickers marks along every
wall, narrowing doorways from one scan to the next. Marks persist
until a ray clears them or :meth:`Costmap.clear_around` removes them. Only the window around
cells whose lethal state a scan changed is re-inflated (the ``updateBounds`` idea), so an update
is cheap on big maps.

The master grid returned by :meth:`Costmap.costs` is an immutable snapshot (read-only array,
replaced, never modified in place) so a planner may use it from another thread while the
costmap keeps updating.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import CostmapConfig
from curio.core.distance import dilate_square, distance_to_features
from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage, LaserScan
from curio.core.pose_history import PoseHistory
from curio.core.topics import COSTMAP, LOCAL_COSTMAP, MAP, POSE, SCAN
from curio.estimation.maps import OccupancyGrid
from curio.nav.costmap_kernels import trace_scan
from curio.nav.costs import INSCRIBED, LETHAL, NO_INFORMATION, inflation_costs
from curio.robot import RobotModel, footprint_radii

__all__ = ["Costmap", "CostmapNode", "GridInfo", "MarkFilter", "costs_to_percent"]

log = logging.getLogger("curio.nav.costmap")

# Between two updates (0.2 s) the rover moves a few centimetres: a bigger jump of its pose in
# map is a relocalisation (or a pose set on the map).
RELOCALISATION_JUMP_M = 0.5

U8Array = npt.NDArray[np.uint8]
BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class GridInfo:
    """Where a cost grid lies.

    Attributes:
        resolution_m: cell size, metres.
        origin: pose of cell (0, 0)'s lower-left corner in ``map``.
        shape: ``(rows, cols)`` = ``(height, width)``.
    """

    resolution_m: float
    origin: Pose2D
    shape: tuple[int, int]


# Nav2's costmap → OccupancyGrid translation for display: 0 → 0, 1..252 → 1..98, 253 → 99,
# 254 → 100, 255 → −1.
_PERCENT_LUT = np.empty(256, dtype=np.int8)
_PERCENT_LUT[0] = 0
_PERCENT_LUT[1:253] = (1 + (97 * (np.arange(1, 253) - 1)) // 251).astype(np.int8)
_PERCENT_LUT[253] = 99
_PERCENT_LUT[254] = 100
_PERCENT_LUT[255] = -1


def costs_to_percent(costs: U8Array) -> npt.NDArray[np.int8]:
    """Scale costs 0..255 to the 0..100 / −1 range of an occupancy grid (for display)."""
    return np.asarray(_PERCENT_LUT[costs], dtype=np.int8)


class Costmap:
    """The global costmap: static + obstacle layers, inflated, on the static map's grid.

    Not thread-safe for updates (call the update methods from one task); the arrays returned by
    :meth:`costs` are immutable snapshots and safe to read from any thread.
    """

    def __init__(self, static_map: OccupancyGrid, robot: RobotModel, cfg: CostmapConfig) -> None:
        self.cfg = cfg
        self.robot = robot
        self.footprint = robot.padded_footprint(cfg.footprint_padding_m)
        self.inscribed_radius_m, self.circumscribed_radius_m = footprint_radii(self.footprint)
        self.laser_in_base = robot.laser_in_base
        self.version = 0
        self._set_static(static_map)

    # ------------------------------------------------------------------ static layer
    def _set_static(self, static_map: OccupancyGrid) -> None:
        self.static_map = static_map
        self.resolution_m = float(static_map.resolution_m)
        self.origin = static_map.origin
        self._origin_inv = static_map.origin.inverse()
        h, w = static_map.height, static_map.width
        self._static_lethal: BoolArray = static_map.occupied_mask() | static_map.edge_mask()
        self._near_static = self._near_static_mask(self._static_lethal)
        self._unknown: BoolArray = static_map.unknown_mask() & ~self._static_lethal
        self._obstacles: BoolArray = np.zeros((h, w), dtype=bool)
        self._keepout: BoolArray = np.zeros((h, w), dtype=bool)  # zones (set_keepout)
        self._seen: BoolArray = np.zeros((h, w), dtype=bool)
        self._touched = np.zeros((h, w), dtype=np.uint8)  # trace_scan's scratch
        self._margin_cells = math.ceil(self.cfg.inflation_radius_m / self.resolution_m) + 1
        self._footprint_samples = self._make_footprint_samples()
        master = self._inflate(self._static_lethal | self._keepout)
        self._apply_unknown(master, (slice(0, h), slice(0, w)))
        master.setflags(write=False)
        self._master: U8Array = master
        self.version += 1

    def set_static_map(self, static_map: OccupancyGrid) -> None:
        """Replace the static layer with a new or updated map.

        A map on the same grid (shape, resolution, origin) — e.g. one growing during
        mapping — is applied incrementally: only the window around the changed cells is
        re-inflated and the obstacle layer is kept. A map on another grid rebuilds everything
        (the obstacle layer starts empty).
        """
        old = self.static_map
        if (static_map.data.shape != old.data.shape
                or static_map.resolution_m != old.resolution_m
                or static_map.origin != old.origin):
            self._set_static(static_map)
            return
        lethal = static_map.occupied_mask() | static_map.edge_mask()
        unknown = static_map.unknown_mask() & ~lethal
        changed = (lethal != self._static_lethal) | (unknown != self._unknown)
        self.static_map = static_map
        if not changed.any():
            return
        self._static_lethal = lethal
        self._near_static = self._near_static_mask(lethal)
        self._unknown = unknown
        rr = np.flatnonzero(changed.any(axis=1))
        cc = np.flatnonzero(changed.any(axis=0))
        m = self._margin_cells
        self._recompute(int(rr[0]) - m, int(rr[-1]) + 1 + m, int(cc[0]) - m, int(cc[-1]) + 1 + m)

    def _near_static_mask(self, lethal: BoolArray) -> BoolArray:
        """Free cells within ``static_mark_tolerance_cells`` of a mapped wall (8-connected)."""
        n = self.cfg.static_mark_tolerance_cells
        if n <= 0 or not lethal.any():
            return np.zeros(lethal.shape, dtype=bool)
        grown = dilate_square(lethal, n)
        return np.asarray(grown & ~lethal)

    @property
    def grid_info(self) -> GridInfo:
        """Resolution, origin and shape of the master grid."""
        return GridInfo(self.resolution_m, self.origin, self._master.shape)  # type: ignore[arg-type]

    @property
    def cost_scaling_factor(self) -> float:
        """The inflation's exponential decay rate (``nav.costmap.cost_scaling_factor``), 1/m."""
        return self.cfg.cost_scaling_factor

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the master grid."""
        return (int(self._master.shape[0]), int(self._master.shape[1]))

    def costs(self) -> U8Array:
        """The master cost grid (read-only snapshot; a new array after every change)."""
        return self._master

    def obstacle_mask(self) -> BoolArray:
        """Cells marked by the obstacle layer (a copy)."""
        return self._obstacles.copy()

    # ------------------------------------------------------------------ inflation
    def _inflate(self, lethal: BoolArray) -> U8Array:
        """Inflated costs for a whole lethal mask (distances measured inside this array)."""
        if not lethal.any():
            return np.zeros(lethal.shape, dtype=np.uint8)
        dist_cells = distance_to_features(lethal)  # SciPy's EDT, bit for bit, without SciPy
        return inflation_costs(np.asarray(dist_cells) * self.resolution_m,
                               self.inscribed_radius_m, self.cfg.inflation_radius_m,
                               self.cfg.cost_scaling_factor)

    def _apply_unknown(self, master: U8Array, region: tuple[slice, slice]) -> None:
        unknown = self._unknown[region] & ~self._seen[region] & ~self._obstacles[region]
        sub = master[region]
        sub[unknown & (sub < INSCRIBED)] = NO_INFORMATION

    def _recompute(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Re-inflate output rows ``r0:r1`` and cols ``c0:c1`` (clipped) into a new master."""
        h, w = self.shape
        r0, r1, c0, c1 = max(0, r0), min(h, r1), max(0, c0), min(w, c1)
        if r0 >= r1 or c0 >= c1:
            return
        m = self._margin_cells
        R0, R1, C0, C1 = max(0, r0 - m), min(h, r1 + m), max(0, c0 - m), min(w, c1 + m)
        lethal = (self._static_lethal[R0:R1, C0:C1] | self._obstacles[R0:R1, C0:C1]
                  | self._keepout[R0:R1, C0:C1])
        sub = self._inflate(lethal)[r0 - R0:r1 - R0, c0 - C0:c1 - C0]
        master = self._master.copy()
        master[r0:r1, c0:c1] = sub
        self._apply_unknown(master, (slice(r0, r1), slice(c0, c1)))
        master.setflags(write=False)
        self._master = master
        self.version += 1

    # ------------------------------------------------------------------ coordinates
    def _to_grid(self, xy_m: FloatArray) -> FloatArray:
        """``(N, 2)`` map points → continuous ``(col, row)`` grid coordinates (cells)."""
        return self._origin_inv.transform_points(xy_m) / self.resolution_m

    def world_to_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """``(row, col)`` of the cell holding map point (x, y) (may lie outside the grid)."""
        lx, ly = self._origin_inv.transform_point(x_m, y_m)
        return (math.floor(ly / self.resolution_m), math.floor(lx / self.resolution_m))

    def cell_to_world(self, row: int, col: int) -> tuple[float, float]:
        """Map coordinates of the centre of cell ``(row, col)``."""
        return self.origin.transform_point((col + 0.5) * self.resolution_m,
                                           (row + 0.5) * self.resolution_m)

    def in_bounds(self, row: int, col: int) -> bool:
        """Whether ``(row, col)`` lies inside the grid."""
        h, w = self.shape
        return 0 <= row < h and 0 <= col < w

    def cost_at(self, x_m: float, y_m: float) -> int:
        """Cost of the cell under map point (x, y); ``LETHAL`` outside the grid."""
        r, c = self.world_to_cell(x_m, y_m)
        if not self.in_bounds(r, c):
            return LETHAL
        return int(self._master[r, c])

    def is_lethal(self, x_m: float, y_m: float) -> bool:
        """Whether the rover's centre at map point (x, y) collides (cost ≥ 253, or off-grid).

        Unknown cells (255) count as lethal here.
        """
        return self.cost_at(x_m, y_m) >= INSCRIBED

    # ------------------------------------------------------------------ obstacle layer
    def update_from_scan(self, scan: LaserScan, pose_in_map: Pose2D,
                         skip_marks: BoolArray | None = None) -> None:
        """Mark and clear the obstacle layer from one scan taken at ``pose_in_map`` (base_link).

        Clearing runs first (every cell a ray crosses before its end point), then marking (the
        end points of returns within ``obstacle_range_m``), so a return always wins over a
        clearing ray of the same scan. Inflation is recomputed only where marks changed.
        Beams flagged in ``skip_marks`` (a walking person's) clear but do not mark.
        """
        n = len(scan.ranges_m)
        if n == 0:
            return
        res = self.resolution_m
        laser = pose_in_map @ self.laser_in_base
        ranges = np.asarray(scan.ranges_m, dtype=np.float64)
        angles = scan.angles_rad + laser.yaw
        with np.errstate(invalid="ignore"):
            finite_valid = scan.valid_mask()
            inf_ray = np.isposinf(ranges) if self.cfg.inf_is_valid else np.zeros(n, dtype=bool)
            # returns beyond the sensor's maximum behave as "nothing seen up to there"
            beyond = np.isfinite(ranges) & (ranges > scan.range_max_m)
        clear_len = np.where(finite_valid, np.minimum(ranges, self.cfg.raytrace_range_m), 0.0)
        clear_len = np.where(inf_ray | beyond,
                             min(self.cfg.raytrace_range_m, scan.range_max_m), clear_len)
        # Ray origin and directions in continuous grid coordinates (cells).
        o = self._to_grid(np.array([[laser.x, laser.y]]))[0]
        rot = angles - self.origin.yaw  # directions rotated into the grid frame
        dirs = np.stack([np.cos(rot), np.sin(rot)], axis=1)
        # Marking: finite returns within the obstacle range.
        mark = finite_valid & (ranges <= self.cfg.obstacle_range_m)
        if skip_marks is not None:
            mark &= ~skip_marks
        mark_len = np.where(mark, ranges / res, -1.0)
        box = np.empty(8, dtype=np.int64)
        changed = trace_scan(self._obstacles, self._seen, self._static_lethal,
                             self._near_static, self._unknown, self._master,
                             float(o[0]), float(o[1]), dirs, clear_len / res, mark_len,
                             self._touched, box)
        r0, r1, c0, c1, vr0, vr1, vc0, vc1 = (int(v) for v in box)
        if changed:
            m = self._margin_cells
            self._recompute(r0 - m, r1 + m, c0 - m, c1 + m)
        elif vr0 < vr1:
            self._recompute(vr0, vr1, vc0, vc1)

    def clear_around(self, pose_in_map: Pose2D, radius_m: float) -> None:
        """Remove obstacle-layer marks within ``radius_m`` of the pose (a recovery action).

        The static map is untouched.
        """
        r, c = self.world_to_cell(pose_in_map.x, pose_in_map.y)
        rad = math.ceil(radius_m / self.resolution_m)
        h, w = self.shape
        r0, r1, c0, c1 = max(0, r - rad), min(h, r + rad + 1), max(0, c - rad), min(w, c + rad + 1)
        if r0 >= r1 or c0 >= c1:
            return
        rr, cc = np.mgrid[r0:r1, c0:c1]
        within = (rr - r) ** 2 + (cc - c) ** 2 <= rad * rad
        window = self._obstacles[r0:r1, c0:c1]
        if not (window & within).any():
            return
        window[within] = False
        m = self._margin_cells
        self._recompute(r0 - m, r1 + m, c0 - m, c1 + m)

    def set_keepout(self, mask: BoolArray) -> None:
        """The keep-out layer: cells of keep-out zones drawn on the map (``curio/zones``),
        lethal like a wall and inflated with the rest, so no plan and no checked trajectory
        enters them. Scans never clear them; a new static map on another grid drops them.

        Raises:
            ValueError: ``mask`` is not of the costmap's shape.
        """
        if mask.shape != self._keepout.shape:
            raise ValueError(f"keep-out mask of shape {mask.shape}, the costmap is "
                             f"{self._keepout.shape}")
        changed = mask != self._keepout
        if not changed.any():
            return
        self._keepout = np.array(mask, dtype=bool)
        rr = np.flatnonzero(changed.any(axis=1))
        cc = np.flatnonzero(changed.any(axis=0))
        m = self._margin_cells
        self._recompute(int(rr[0]) - m, int(rr[-1]) + 1 + m, int(cc[0]) - m, int(cc[-1]) + 1 + m)

    def keepout_mask(self) -> BoolArray:
        """Cells of the keep-out layer (a copy)."""
        return self._keepout.copy()

    def clear_spots(self, spots: list[tuple[float, float]], radius_m: float) -> bool:
        """Remove obstacle-layer marks within ``radius_m`` of each map point (where a walking
        person is or was); re-inflate once round all of them. Whether any mark went."""
        if not spots or radius_m <= 0.0:
            return False
        rad = math.ceil(radius_m / self.resolution_m)
        h, w = self.shape
        box = [h, 0, w, 0]
        for x, y in spots:
            r, c = self.world_to_cell(x, y)
            r0, r1, c0, c1 = max(0, r - rad), min(h, r + rad + 1), max(0, c - rad), min(
                w, c + rad + 1)
            if r0 >= r1 or c0 >= c1:
                continue
            window = self._obstacles[r0:r1, c0:c1]
            if not window.any():
                continue
            rr, cc = np.ogrid[r0:r1, c0:c1]
            within = (rr - r) ** 2 + (cc - c) ** 2 <= rad * rad
            if not (window & within).any():
                continue
            window[within] = False
            box = [min(box[0], r0), max(box[1], r1), min(box[2], c0), max(box[3], c1)]
        if box[0] >= box[1]:
            return False
        m = self._margin_cells
        self._recompute(box[0] - m, box[1] + m, box[2] - m, box[3] + m)
        return True

    def reset_obstacles(self) -> None:
        """Forget every obstacle-layer mark (the static map stays)."""
        if self._obstacles.any():
            self._obstacles[:] = False
            h, w = self.shape
            self._recompute(0, h, 0, w)

    # ------------------------------------------------------------------ footprint
    def _make_footprint_samples(self) -> FloatArray:
        """Points covering the padded footprint (interior grid + perimeter), base_link, m."""
        poly = self.footprint
        step = self.resolution_m * 0.5
        xmin, ymin = poly.min(axis=0)
        xmax, ymax = poly.max(axis=0)
        xs = np.arange(xmin, xmax + step * 0.5, step)
        ys = np.arange(ymin, ymax + step * 0.5, step)
        gx, gy = np.meshgrid(xs, ys)
        pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
        inside = _points_in_polygon(pts, poly)
        perim = []
        for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
            n = max(2, math.ceil(float(np.hypot(*(b - a))) / step) + 1)
            tt = np.linspace(0.0, 1.0, n)[:, None]
            perim.append(a + tt * (b - a))
        return np.concatenate([pts[inside], *perim], axis=0)

    def footprint_costs(self, poses_in_map: FloatArray) -> U8Array:
        """Max cost under the footprint for each pose of an ``(N, 3)`` array ``[x, y, yaw]``.

        Poses whose footprint leaves the grid get ``LETHAL``. ``>= LETHAL`` (254) means the
        footprint overlaps an obstacle; 255 that it covers unknown space.
        """
        p = np.asarray(poses_in_map, dtype=np.float64).reshape(-1, 3)
        s = self._footprint_samples
        cy, sy = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
        x = p[:, 0:1] + cy * s[None, :, 0] - sy * s[None, :, 1]
        y = p[:, 1:2] + sy * s[None, :, 0] + cy * s[None, :, 1]
        g = self._to_grid(np.stack([x.ravel(), y.ravel()], axis=1))
        cols = np.floor(g[:, 0]).astype(np.int64)
        rows = np.floor(g[:, 1]).astype(np.int64)
        h, w = self.shape
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        vals = np.full(rows.shape, LETHAL, dtype=np.uint8)
        vals[inside] = self._master[rows[inside], cols[inside]]
        return np.asarray(vals.reshape(p.shape[0], -1).max(axis=1), dtype=np.uint8)

    def footprint_cost(self, pose_in_map: Pose2D) -> int:
        """Max cost under the footprint polygon at ``pose_in_map`` (``LETHAL`` if off-grid)."""
        return int(self.footprint_costs(np.array([[pose_in_map.x, pose_in_map.y,
                                                   pose_in_map.yaw]]))[0])

    # ------------------------------------------------------------------ local window
    def local_window(self, pose_in_map: Pose2D, size_m: float | None = None
                     ) -> tuple[U8Array, Pose2D]:
        """The rolling window (``local_window_m`` square) centred on the rover.

        Returns ``(costs, origin)``: a copy of the master costs in the window (cells outside the
        map are ``NO_INFORMATION``) and the pose of its cell (0, 0)'s lower-left corner in
        ``map``. The window is aligned to the master grid's cells.
        """
        size = self.cfg.local_window_m if size_m is None else size_m
        n = max(1, round(size / self.resolution_m))
        r, c = self.world_to_cell(pose_in_map.x, pose_in_map.y)
        r0, c0 = r - n // 2, c - n // 2
        out = np.full((n, n), NO_INFORMATION, dtype=np.uint8)
        h, w = self.shape
        sr0, sr1, sc0, sc1 = max(0, r0), min(h, r0 + n), max(0, c0), min(w, c0 + n)
        if sr0 < sr1 and sc0 < sc1:
            out[sr0 - r0:sr1 - r0, sc0 - c0:sc1 - c0] = self._master[sr0:sr1, sc0:sc1]
        origin = self.origin @ Pose2D(c0 * self.resolution_m, r0 * self.resolution_m, 0.0)
        return out, origin

    # ------------------------------------------------------------------ messages
    def to_message(self, stamp: float, kind: str = "costmap") -> GridMessage:
        """The master grid as a display message (costs scaled to 0..100, unknown −1)."""
        return GridMessage(stamp=stamp, data=costs_to_percent(self._master),
                           resolution_m=self.resolution_m, origin=self.origin,
                           version=self.version, kind=kind, frame_id="map")

    def local_message(self, stamp: float, pose_in_map: Pose2D,
                      kind: str = "local_costmap") -> GridMessage:
        """The rolling window around ``pose_in_map`` as a display message."""
        costs, origin = self.local_window(pose_in_map)
        return GridMessage(stamp=stamp, data=costs_to_percent(costs),
                           resolution_m=self.resolution_m, origin=origin,
                           version=self.version, kind=kind, frame_id="map")


def _points_in_polygon(pts: FloatArray, poly: FloatArray) -> BoolArray:
    """Even-odd test of ``(N, 2)`` points against a polygon ``(M, 2)``."""
    x, y = pts[:, 0:1], pts[:, 1:2]
    x1, y1 = poly[None, :, 0], poly[None, :, 1]
    x2, y2 = np.roll(poly, -1, axis=0)[None, :, 0], np.roll(poly, -1, axis=0)[None, :, 1]
    cond = (y1 > y) != (y2 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
    crosses = cond & (x < xint)
    return np.asarray(crosses.sum(axis=1) % 2 == 1)


class MarkFilter(Protocol):
    """Tells the obstacle layer which returns not to mark and where to clear: the people
    tracker (``curio/people/node.py``) keeps walking people out of the costmap."""

    @property
    def clear_radius_m(self) -> float:
        """Marks this near a cleared spot are removed, metres."""

    def beams_to_skip(self, scan: LaserScan) -> BoolArray | None:
        """Beams of ``scan`` to clear along but not mark (None: mark every return)."""

    def cleared_spots(self) -> list[tuple[float, float]]:
        """Map points (metres) round which marks are to be removed now."""


class CostmapNode:
    """Runs a :class:`Costmap` on the bus.

    Subscribes ``SCAN`` and ``POSE`` (and ``MAP``: a new map updates the static layer), updates
    at ``update_rate_hz`` with the newest scan, placed with the rover's pose at the scan's stamp
    (interpolated in the recent ``POSE`` history; the newest pose if the stamp lies outside
    it), publishes ``COSTMAP`` when the master grid changed (at most
    ``global_publish_rate_hz``; ``version`` increases) and ``LOCAL_COSTMAP`` (the rolling
    window around the newest pose) every update.
    """

    def __init__(self, costmap: Costmap, bus: Bus, clock: Clock, cfg: CostmapConfig) -> None:
        self.costmap = costmap
        self.bus = bus
        self.clock = clock
        self.cfg = cfg
        self.updates = 0
        self._published_version = -1
        self._last_global_publish = -math.inf
        self._last_scan_stamp = -math.inf
        self._pose_sub = bus.subscribe(POSE, maxsize=256)
        self._poses = PoseHistory(256, interpolation="linear")
        self._last_pose: Pose2D | None = None
        self.relocalisation_resets = 0
        # The people tracker when people.aware (None: every return is marked, the baseline).
        self.mark_filter: MarkFilter | None = None

    def pose_at(self, stamp: float) -> Pose2D | None:
        """The rover's pose in ``map`` at ``stamp``, from the recent ``POSE`` history."""
        for msg in self._pose_sub.drain():
            self._poses.add(msg.stamp, msg.pose)
        if not self._poses:
            latest = self.bus.latest(POSE)
            return None if latest is None else latest.pose
        return self._poses.at(stamp)

    def step(self, now: float) -> None:
        """One update: apply the newest scan (if new) and publish."""
        scan = self.bus.latest(SCAN)
        pose = self.pose_at(math.inf)
        if pose is None:
            return
        self._forget_marks_on_jump(pose)
        if scan is not None and scan.stamp != self._last_scan_stamp:
            self._last_scan_stamp = scan.stamp
            scan_pose = self.pose_at(scan.stamp)
            people = self.mark_filter
            skip = people.beams_to_skip(scan) if people is not None else None
            self.costmap.update_from_scan(scan, scan_pose if scan_pose is not None else pose,
                                          skip)
            if people is not None:
                self.costmap.clear_spots(people.cleared_spots(), people.clear_radius_m)
            self.updates += 1
        cm = self.costmap
        if (cm.version != self._published_version
                and now - self._last_global_publish >= 1.0 / self.cfg.global_publish_rate_hz):
            self.bus.publish(COSTMAP, cm.to_message(now))
            self._published_version = cm.version
            self._last_global_publish = now
        self.bus.publish(LOCAL_COSTMAP, cm.local_message(now, pose))

    def _forget_marks_on_jump(self, pose: Pose2D) -> None:
        """The rover's pose in ``map`` jumped (relocalisation, a pose set on the map): the
        obstacle marks were placed with the old pose, so they are wrong; forget them."""
        last, self._last_pose = self._last_pose, pose
        if last is not None and last.distance_to(pose) > RELOCALISATION_JUMP_M:
            self.costmap.reset_obstacles()
            self.relocalisation_resets += 1
            log.info("costmap: the pose jumped %.2f m (relocalised): obstacle marks cleared",
                     last.distance_to(pose))

    async def run(self) -> None:
        """Update at ``update_rate_hz`` until cancelled."""
        map_sub = self.bus.subscribe(MAP)
        async for now in self.clock.every(1.0 / self.cfg.update_rate_hz, immediate=True):
            for grid_msg in map_sub.drain():
                self._take_map(grid_msg)
            self.step(now)

    def _take_map(self, msg: GridMessage) -> None:
        if msg.kind != "map":
            return
        old = self.costmap.static_map
        if (msg.data.shape == old.data.shape and msg.resolution_m == old.resolution_m
                and msg.origin == old.origin and np.array_equal(msg.data, old.data)):
            return
        grid = OccupancyGrid(np.asarray(msg.data, dtype=np.int8), msg.resolution_m, msg.origin,
                             old.occupied_thresh, old.free_thresh, old.name)
        self.costmap.set_static_map(grid)
        log.info("costmap: static layer updated from a new map (%dx%d)", grid.width, grid.height)
