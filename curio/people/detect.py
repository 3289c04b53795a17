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

    def distance_at(self, xy: F64) -> F64:
        """Distance (m) to the map's nearest obstacle at each ``(N, 2)`` map point (−1 outside
        the map)."""
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
        valid = scan.valid_mask() & (ranges <= self.cfg.max_range_m)
        idx = np.flatnonzero(valid)
        r = ranges[idx]
        ang = scan.angle_min_rad + idx * scan.angle_increment_rad + laser.yaw
        pts = np.column_stack([laser.x + r * np.cos(ang), laser.y + r * np.sin(ang)])
        keep = self.static.distance_at(pts) > self.cfg.static_margin_m
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
        if circle_beams and len(idx) > 1:
            idx, pts, r = _start_after_a_split(idx, pts, r, circle_beams,
                                               self.cfg.segment_gap_m)
        step = np.diff(idx) % circle_beams if circle_beams else np.diff(idx)
        gap = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
        split = (gap > self.cfg.segment_gap_m + 0.01 * r[1:]) | (step > 3)
        starts = np.concatenate([[0], np.flatnonzero(split) + 1])
        ends = np.concatenate([starts[1:], [len(idx)]])
        counts = ends - starts
        cx = np.add.reduceat(pts[:, 0], starts) / counts
        cy = np.add.reduceat(pts[:, 1], starts) / counts
        width = np.hypot(pts[ends - 1, 0] - pts[starts, 0], pts[ends - 1, 1] - pts[starts, 1])
        keep = (width <= self.cfg.max_width_m) & ((counts >= 2) | (r[starts] >= 3.0))
        return [(float(cx[k]), float(cy[k]), max(float(width[k]), 0.05),
                 idx[starts[k]:ends[k]]) for k in np.flatnonzero(keep).tolist()
                if width[k] <= FLAT_MIN_WIDTH_M or not _flat(pts[starts[k]:ends[k]])]

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
        pairs = sorted((math.hypot(pushed[a][0] - pushed[b][0], pushed[a][1] - pushed[b][1]),
                        a, b) for i, a in enumerate(legs) for b in legs[i + 1:])
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


def _start_after_a_split(idx: I64, pts: F64, r: F64, n: int,
                         gap_m: float) -> tuple[I64, F64, F64]:
    """The returns of a full-circle scan of ``n`` beams reordered (cyclically) to start just
    after a split between segments, so no segment straddles the seam between the last beam and
    the first; unchanged when the seam already is a split (or there is none at all)."""
    step = (np.roll(idx, -1) - idx) % n
    nxt = np.roll(pts, -1, axis=0)
    gap = np.hypot(nxt[:, 0] - pts[:, 0], nxt[:, 1] - pts[:, 1])
    split = (gap > gap_m + 0.01 * np.roll(r, -1)) | (step > 3)
    if split[-1] or not split.any():
        return idx, pts, r
    k = int(np.flatnonzero(split)[-1]) + 1
    return np.roll(idx, -k), np.roll(pts, -k, axis=0), np.roll(r, -k)


def _flat(seg: F64, rms_m: float = FLAT_RMS_M) -> bool:
    """Whether the points of ``seg`` (``(N, 2)``, m) lie on a line: the RMS distance to their
    best-fitting line is at most ``rms_m`` (a body or a pair of legs is an arc, not a line)."""
    if len(seg) < 5:
        return False
    c = seg - seg.mean(axis=0)
    smallest = float(np.linalg.eigvalsh(c.T @ c / len(seg))[0])
    return math.sqrt(max(smallest, 0.0)) <= rms_m
