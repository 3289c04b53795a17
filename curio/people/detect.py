"""People detections from one lidar scan: the returns that are not the static map, grouped.

Steps (all in ``map`` metres; the scan is placed with the laser's pose at its stamp):

1. **Not the map** — valid returns within ``max_range_m`` whose end point lies more than
   ``static_margin_m`` from every occupied cell of the static map (a distance transform of
   the map, computed once per map). Returns outside the map are ignored.
2. **Segments** — neighbouring returns in beam order (at most two beams apart) closer than
   ``segment_gap_m`` + 1 % of the range form one segment (in a full-circle scan the last
   beam neighbours the first: a segment across that seam is one segment). A segment wider
   than ``max_width_m`` is not a person (a wall not on the map, a closed door), nor is one
   wider than a body whose points lie on a line (a flat panel: a door, a board).
3. **Legs and bodies** — a low lidar sees legs: two segments up to ``leg_width_m`` wide whose
   centres are within ``leg_pair_m`` are paired (nearest pairs first) into one person; an
   unpaired leg (the other hidden) and a wider segment (a body, a bag) are a person each.

A segment's centre is its points' mean pushed away from the sensor by 0.64 × its half width
(the distance from a circle's centre to the mean of the half of it a sensor sees), so a
detection estimates the centre of the leg or body, not its near surface. Each detection keeps
the beam indices it was made of (the costmap leaves them unmarked when they belong to a
walking person).

The loops over returns and segments run compiled (:mod:`curio.people.tracking_kernel`) with
numpy's operations in numpy's order — the same bits; the trigonometry, the flat-panel fit and
the pairing of legs (Python's ``math.hypot``) stay in numpy and Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from curio.core.config import PeopleConfig
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan
from curio.estimation.maps import OccupancyGrid
from curio.people.tracking_kernel import (
    beam_angles,
    close_pairs,
    end_points_off_map,
    map_distances,
    scan_segments,
)

__all__ = ["Detection", "Detector", "StaticMap"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

ARC_CENTRE = 2.0 / math.pi  # mean of a half circle's points, as a fraction of its radius
# A segment wider than a body whose points lie on a line (RMS distance to it at most the
# lidar's noise, a few cm) is a flat panel — a closed door, a board — not a person.
FLAT_MIN_WIDTH_M = 0.45
FLAT_RMS_M = 0.03


@dataclass(frozen=True, slots=True)
class Detection:
    """One person seen in a scan: centre (map, metres), width (m) and the beams it is made of."""

    x_m: float
    y_m: float
    width_m: float
    beams: I64


class StaticMap:
    """Distance (m) from each cell of the static map to its nearest occupied cell.

    Args:
        grid: the static map (``map``; its origin may be rotated).
    """

    def __init__(self, grid: OccupancyGrid) -> None:
        self.grid = grid
        occ = grid.occupied_mask()
        dist = ndimage.distance_transform_edt(~occ) if occ.any() else np.full(occ.shape, 1e9)
        self.distance_m: F64 = np.asarray(dist, dtype=np.float64) * grid.resolution_m
        self._inv = grid.origin.inverse()
        # An origin without rotation: map point p lies in cell floor((p + offset) / resolution)
        # — what distance_at computes (its product with the identity rotation adds only exact
        # zeros); the detector's compiled foreground does it so.
        self.axis_aligned = (math.cos(self._inv.yaw) == 1.0
                             and math.sin(self._inv.yaw) == 0.0)
        self.offset_m = (float(self._inv.x), float(self._inv.y))

    def distance_at(self, xy: F64) -> F64:
        """Distance (m) to the map's nearest obstacle at each ``(N, 2)`` map point (−1 outside
        the map)."""
        if self.axis_aligned:
            out: F64 = map_distances(np.ascontiguousarray(xy, dtype=np.float64),
                                     *self.offset_m, float(self.grid.resolution_m),
                                     self.distance_m)
            return out
        g = self._inv.transform_points(xy) / self.grid.resolution_m
        col = np.floor(g[:, 0]).astype(np.int64)
        row = np.floor(g[:, 1]).astype(np.int64)
        h, w = self.distance_m.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        out = np.full(len(xy), -1.0)
        out[inside] = self.distance_m[row[inside], col[inside]]
        return out


class Detector:
    """Turns scans into :class:`Detection` s (see the module docstring).

    Args:
        cfg: ``people``.
        static: the static map's distance field.
    """

    def __init__(self, cfg: PeopleConfig, static: StaticMap) -> None:
        self.cfg = cfg
        self.static = static

    def foreground(self, scan: LaserScan, laser: Pose2D) -> tuple[I64, F64, F64]:
        """The beams (indices), end points (map) and ranges of returns not on the map."""
        ranges = np.asarray(scan.ranges_m, dtype=np.float64)
        idx, r, ang = beam_angles(scan.valid_mask(), ranges, float(self.cfg.max_range_m),
                                  float(scan.angle_min_rad), float(scan.angle_increment_rad),
                                  float(laser.yaw))
        c, s = np.cos(ang), np.sin(ang)
        static = self.static
        if static.axis_aligned:
            out: tuple[I64, F64, F64] = end_points_off_map(
                idx, float(laser.x), float(laser.y), r, c, s, *static.offset_m,
                float(static.grid.resolution_m), static.distance_m,
                float(self.cfg.static_margin_m))
            return out
        pts = np.column_stack([laser.x + r * c, laser.y + r * s])
        keep = static.distance_at(pts) > self.cfg.static_margin_m
        return idx[keep], pts[keep], r[keep]

    def detect(self, scan: LaserScan, laser: Pose2D) -> list[Detection]:
        """The people in ``scan``, taken at ``laser`` (the laser's pose in ``map``)."""
        idx, pts, r = self.foreground(scan, laser)
        if len(idx) == 0:
            return []
        n = len(scan.ranges_m)
        circle = abs(n * scan.angle_increment_rad - 2.0 * math.pi) < 1.5 * abs(
            scan.angle_increment_rad)
        segments = self._segments(idx, pts, r, n if circle else 0)
        return self._people(segments, (laser.x, laser.y))

    def _segments(self, idx: I64, pts: F64, r: F64,
                  circle_beams: int = 0) -> list[tuple[float, float, float, I64]]:
        """``(x, y, width, beams)`` of each segment (centre: the mean of its points).

        ``circle_beams``: the scan's beam count when it covers the full circle (its last beam
        neighbours its first: a segment across that seam is one segment, not two), else 0.
        """
        idx, pts, starts, ends, cx, cy, width, keep = scan_segments(
            np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(pts, np.float64),
            np.ascontiguousarray(r, dtype=np.float64), int(circle_beams),
            float(self.cfg.segment_gap_m), float(self.cfg.max_width_m))
        out = []
        for k in keep.tolist():
            s, e, w = int(starts[k]), int(ends[k]), float(width[k])
            if w <= FLAT_MIN_WIDTH_M or not _flat(pts[s:e]):
                out.append((float(cx[k]), float(cy[k]), max(w, 0.05), idx[s:e]))
        return out

    def _people(self, segments: list[tuple[float, float, float, I64]],
                sensor: tuple[float, float]) -> list[Detection]:
        """Pair leg-sized segments, push centres away from the sensor, make detections."""
        pushed = []
        for cx, cy, width, beams in segments:
            dx, dy = cx - sensor[0], cy - sensor[1]
            d = math.hypot(dx, dy) or 1.0
            push = ARC_CENTRE * 0.5 * width
            pushed.append((cx + push * dx / d, cy + push * dy / d, width, beams))
        legs = [k for k, s in enumerate(pushed) if s[2] <= self.cfg.leg_width_m]
        pairs = sorted(self._close_pairs(pushed, legs))
        used: set[int] = set()
        out = []
        for d, a, b in pairs:
            if d > self.cfg.leg_pair_m:
                break
            if a in used or b in used:
                continue
            used.update((a, b))
            sa, sb = pushed[a], pushed[b]
            out.append(Detection(0.5 * (sa[0] + sb[0]), 0.5 * (sa[1] + sb[1]), d + sa[2],
                                 np.concatenate([sa[3], sb[3]])))
        for k, s in enumerate(pushed):
            if k not in used:
                out.append(Detection(s[0], s[1], s[2], s[3]))
        return out

    def _close_pairs(self, pushed: list[tuple[float, float, float, I64]],
                     legs: list[int]) -> list[tuple[float, int, int]]:
        """``(distance, a, b)`` of the pairs of ``legs`` (``a`` before ``b`` in ``legs``) that
        may be within ``leg_pair_m``: a pair farther apart along x or y (beyond a rounding
        margin) is farther apart than that, and would never be paired. (With a NaN
        coordinate: every pair, as sorting them all gave their order.)"""
        if len(legs) < 2:
            return []
        first, second = close_pairs(np.array([pushed[k][:2] for k in legs], dtype=np.float64),
                                    float(self.cfg.leg_pair_m) + 1e-9)
        out = []
        for i, j in zip(first.tolist(), second.tolist(), strict=True):
            a, b = legs[i], legs[j]
            out.append((math.hypot(pushed[a][0] - pushed[b][0], pushed[a][1] - pushed[b][1]),
                        a, b))
        return out


def _flat(seg: F64, rms_m: float = FLAT_RMS_M) -> bool:
    """Whether the points of ``seg`` (``(N, 2)``, m) lie on a line: the RMS distance to their
    best-fitting line is at most ``rms_m`` (a body or a pair of legs is an arc, not a line)."""
    if len(seg) < 5:
        return False
    c = seg - seg.mean(axis=0)
    smallest = float(np.linalg.eigvalsh(c.T @ c / len(seg))[0])
    return math.sqrt(max(smallest, 0.0)) <= rms_m
