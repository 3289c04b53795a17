"""Correlative branch-and-bound search, point-to-line refinement, normals, the log-odds kernel."""

from __future__ import annotations

import math
from itertools import product

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.estimation.log_odds_kernel import integrate_rays
from curio.estimation.scan_matching import (
    LikelihoodGrid,
    PointMap,
    refine,
    scan_normals,
    voxel_subsample,
)
from curio.estimation.scan_matching_kernels import max_pyramid


def _segment(x0: float, y0: float, x1: float, y1: float, step: float = 0.02) -> np.ndarray:
    n = max(2, round(math.hypot(x1 - x0, y1 - y0) / step))
    t = np.linspace(0.0, 1.0, n)
    return np.stack([x0 + (x1 - x0) * t, y0 + (y1 - y0) * t], axis=1)


def room_points() -> np.ndarray:
    """Walls of an asymmetric 8 m × 5 m room with a pillar and a recess (map frame)."""
    return np.vstack([
        _segment(0, 0, 8, 0), _segment(8, 0, 8, 5), _segment(8, 5, 3, 5), _segment(3, 5, 3, 4),
        _segment(3, 4, 0, 4), _segment(0, 4, 0, 0), _segment(5, 2, 5.4, 2),
        _segment(5.4, 2, 5.4, 2.4), _segment(5.4, 2.4, 5, 2.4), _segment(5, 2.4, 5, 2),
    ])


def corridor_points(length: float = 30.0) -> np.ndarray:
    """Two long parallel walls 2 m apart along x (map frame)."""
    return np.vstack([_segment(-length / 2, -1, length / 2, -1),
                      _segment(-length / 2, 1, length / 2, 1)])


def scan_of(points: np.ndarray, pose: Pose2D, max_range: float = 10.0) -> np.ndarray:
    """The reference points seen from ``pose``, in its frame, sorted by bearing."""
    local = pose.inverse().transform_points(points)
    keep = np.hypot(local[:, 0], local[:, 1]) < max_range
    local = local[keep]
    return local[np.argsort(np.arctan2(local[:, 1], local[:, 0]))]


def test_normals_of_a_wall_are_perpendicular_and_trusted() -> None:
    pts = _segment(1.0, -1.0, 1.0, 1.0)  # a wall at x = 1
    normals, ok = scan_normals(pts)
    assert ok[2:-2].all()
    assert np.allclose(np.abs(normals[2:-2, 0]), 1.0, atol=1e-6)
    # Scattered points (clutter) get no trusted normal.
    rng = np.random.default_rng(1)
    _, ok = scan_normals(rng.uniform(-5, 5, (50, 2)))
    assert ok.mean() < 0.2


def test_voxel_subsample_keeps_one_point_per_cell() -> None:
    pts = np.array([[0.01, 0.01], [0.02, 0.03], [0.11, 0.0], [0.12, 0.01], [-0.01, 0.0]])
    keep = voxel_subsample(pts, 0.1)
    assert keep.tolist() == [0, 2, 4]


def test_max_pyramid_bounds_every_block() -> None:
    rng = np.random.default_rng(3)
    grid = rng.random((23, 17)).astype(np.float32)
    pyr = max_pyramid(grid, 3)
    for lev in range(4):
        b = 1 << lev
        for r, c in [(0, 0), (5, 9), (20, 15), (22, 16)]:
            assert pyr[lev, r, c] == pytest.approx(grid[r:r + b, c:c + b].max())


def test_branch_and_bound_finds_a_far_off_pose() -> None:
    ref = room_points()
    truth = Pose2D(2.0, 1.5, 0.4)
    scan = scan_of(ref, truth)
    grid = LikelihoodGrid(ref, 0.05, 0.05, depth=5)
    guess = truth @ Pose2D(0.6, -0.5, math.radians(-12.0))
    found = grid.search(scan[::3], guess, 1.0, math.radians(20.0), math.radians(0.5), 0.3)
    assert found is not None
    pose, score = found
    assert pose.distance_to(truth) < 0.06
    assert abs(math.remainder(pose.yaw - truth.yaw, 2 * math.pi)) < math.radians(0.6)
    assert score > 0.8


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_branch_and_bound_equals_exhaustive_search(seed: int) -> None:
    """The bounds are exact — also for blocks that reach past the grid's edge — so pruning
    never loses the best candidate."""
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0.0, 3.0, (60, 2))
    pts = rng.uniform(-2.5, 2.5, (25, 2))  # many fall off the grid for some offsets
    grid = LikelihoodGrid(ref, 0.1, 0.1, depth=3)
    center = Pose2D(0.3, 2.6, 0.0)
    step = math.radians(2.0)
    found = grid.search(pts, center, 0.7, math.radians(6.0), step, 0.0)
    assert found is not None
    best = max(grid.score(pts, Pose2D(center.x + i * 0.1, center.y + j * 0.1, k * step))
               for i, j, k in product(range(-7, 8), range(-7, 8), range(-3, 4)))
    assert found[1] == pytest.approx(best, rel=1e-5)


def test_runner_up_tells_a_corridor_from_a_room() -> None:
    exclude = 0.3, math.radians(3.0)
    # In a room the best match is unique...
    ref = room_points()
    truth = Pose2D(2.0, 1.5, 0.4)
    scan = scan_of(ref, truth)[::3]
    grid = LikelihoodGrid(ref, 0.05, 0.05, depth=6)
    best = grid.search(scan, truth, 2.0, 0.2, math.radians(1.0), 0.3)
    assert best is not None
    second = grid.search(scan, truth, 2.0, 0.2, math.radians(1.0), 0.9 * best[1],
                         exclude=(best[0], *exclude))
    assert second is None
    # ...in a corridor it is as good a metre further along the axis.
    ref = corridor_points()
    scan = scan_of(ref, Pose2D())[::3]
    grid = LikelihoodGrid(ref, 0.05, 0.05, depth=6)
    best = grid.search(scan, Pose2D(), 2.0, 0.2, math.radians(1.0), 0.3)
    assert best is not None
    second = grid.search(scan, Pose2D(), 2.0, 0.2, math.radians(1.0), 0.9 * best[1],
                         exclude=(best[0], *exclude))
    assert second is not None
    assert abs(second[0].x - best[0].x) > 0.3 and abs(second[0].y - best[0].y) < 0.1


def test_refine_converges_and_reports_the_corridor_axis() -> None:
    ref = room_points()
    normals, ok = scan_normals(ref)
    pmap = PointMap(ref[ok], normals[ok])
    truth = Pose2D(2.0, 1.5, 0.4)
    scan = scan_of(ref, truth)
    r = refine(pmap, scan, truth @ Pose2D(0.08, -0.06, math.radians(2.0)))
    assert r.pose.distance_to(truth) < 0.005
    assert abs(r.pose.yaw - truth.yaw) < math.radians(0.1)
    assert r.inlier_fraction > 0.95
    # A corridor: the information along x (the axis) is next to nothing.
    ref = corridor_points()
    normals, ok = scan_normals(ref)
    pmap = PointMap(ref[ok], normals[ok])
    r = refine(pmap, scan_of(ref, Pose2D(0.0, 0.2, 0.0)), Pose2D(0.0, 0.25, 0.02))
    assert abs(r.pose.y - 0.2) < 0.005 and abs(r.pose.yaw) < math.radians(0.1)
    assert r.info[0, 0] < 1e-3 * r.info[1, 1]
    # With a prior, the open direction follows the prior.
    prior = np.diag([1 / 0.05**2, 1 / 0.05**2, 1 / 0.1**2])
    r = refine(pmap, scan_of(ref, Pose2D(0.0, 0.2, 0.0)), Pose2D(0.3, 0.25, 0.0),
               prior_mean=Pose2D(0.3, 0.25, 0.0), prior_info=prior)
    assert r.pose.x == pytest.approx(0.3, abs=0.01)
    assert r.info_total[0, 0] == pytest.approx(r.info[0, 0] + prior[0, 0])


def _reference_integrate(l_grid: np.ndarray, ox: float, oy: float, res: float,
                         origin: tuple[float, float], ends: np.ndarray, clears: np.ndarray,
                         l_free: float, l_occ: float, l_max: float) -> None:
    """The straightforward numpy version the compiled kernel replaced."""
    w = l_grid.shape[1]
    targets = np.vstack([ends, clears])
    dx, dy = targets[:, 0] - origin[0], targets[:, 1] - origin[1]
    length = np.hypot(dx, dy)
    cols = np.floor((ends[:, 0] - ox) / res).astype(np.int64)
    rows = np.floor((ends[:, 1] - oy) / res).astype(np.int64)
    occ = np.unique(rows * w + cols)
    stop = length.copy()
    stop[:len(ends)] -= res
    free: set[int] = set()
    for k in range(len(targets)):
        n = 0
        while n * 0.8 * res < stop[k]:
            d = n * 0.8 * res / length[k]
            c = math.floor((origin[0] + dx[k] * d - ox) / res)
            r = math.floor((origin[1] + dy[k] * d - oy) / res)
            free.add(r * w + c)
            n += 1
    flat = l_grid.reshape(-1)
    idx = np.array(sorted(free - set(occ.tolist())), dtype=np.int64)
    flat[idx] = np.clip(flat[idx] + l_free, -l_max, l_max)
    flat[occ] = np.clip(flat[occ] + l_occ, -l_max, l_max)


def test_log_odds_kernel_matches_the_reference() -> None:
    rng = np.random.default_rng(2)
    res, ox, oy = 0.05, -6.0, -6.0
    got = np.zeros((240, 240), dtype=np.float32)
    want = np.zeros((240, 240), dtype=np.float32)
    seen = np.zeros(got.shape, dtype=bool)
    mark = np.zeros(got.shape, dtype=np.int64)
    for scan_id in range(1, 6):
        origin = (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)))
        ang = np.linspace(-math.pi, math.pi, 90, endpoint=False)
        rr = rng.uniform(0.5, 4.5, len(ang))
        pts = np.stack([origin[0] + rr * np.cos(ang), origin[1] + rr * np.sin(ang)], axis=1)
        ends, clears = pts[:70], pts[70:]
        integrate_rays(got, seen, mark, scan_id, ox, oy, res, origin[0], origin[1],
                       np.ascontiguousarray(pts), len(ends), -0.4, 0.9, 6.0)
        _reference_integrate(want, ox, oy, res, origin, ends, clears, -0.4, 0.9, 6.0)
    assert np.allclose(got, want, atol=1e-5)
    assert np.array_equal(seen, want != 0) or (seen >= (want != 0)).all()
