"""LaserScan.points with the shared beam trigonometry gives the same points to the last bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan

F64 = np.ndarray


def _ref_points(scan: LaserScan, laser: Pose2D, max_beams: int | None,
                range_max_m: float | None) -> F64:
    """LaserScan.points before the shared trigonometry tables (verbatim)."""
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    valid = scan.valid_mask()
    if range_max_m is not None:
        valid &= ranges <= range_max_m
    idx = np.flatnonzero(valid)
    if max_beams is not None and len(idx) > max_beams:
        pick = np.linspace(0, len(idx) - 1, max_beams).round().astype(np.int64)
        idx = idx[pick]
    ang = scan.angle_min_rad + idx * scan.angle_increment_rad
    r = ranges[idx]
    pts = np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)
    return laser.transform_points(pts)


@pytest.mark.parametrize("beams", [360, 720, 1147])
def test_scan_points_are_unchanged(beams: int) -> None:
    rng = np.random.default_rng(beams)
    laser = Pose2D(0.1, -0.02, 0.03)
    for _ in range(20):
        ranges = rng.uniform(0.05, 14.0, beams).astype(np.float32)
        ranges[rng.random(beams) < 0.1] = np.inf
        ranges[rng.random(beams) < 0.05] = np.nan
        scan = LaserScan(0.0, -math.pi + rng.uniform(0, 0.01), 2 * math.pi / beams, 0.15,
                         12.0, ranges)
        for max_beams, rmax in ((None, None), (60, 11.95), (180, 11.95), (90, None)):
            assert np.array_equal(scan.points(laser, max_beams=max_beams, range_max_m=rmax),
                                  _ref_points(scan, laser, max_beams, rmax))
