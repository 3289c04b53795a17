"""The people detector's, tracker's and node's compiled steps give the same bits as the numpy
and filterpy code they stand for: each is checked against that code (the reference formula,
kept here) on random scans, segments, legs and filter histories. Equal means equal bytes."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan
from curio.estimation.maps import OccupancyGrid
from curio.people.detect import Detection, Detector, StaticMap, _flat
from curio.people.tracker import _predict, _update
from curio.people.tracking_kernel import beams_near, pairwise_sum
from tests.unit.test_people_detect import scan as scan_of
from tests.unit.test_people_tracker import room

F64 = np.ndarray


def same(a: object, b: object) -> bool:
    """Equal to the bit (arrays: dtype, shape and bytes; floats: their bytes)."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, float) and isinstance(b, float):
        return np.float64(a).tobytes() == np.float64(b).tobytes()
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


# -- the reference formulas: the numpy code the kernels replaced -------------------------------
def ref_distance_at(static: StaticMap, xy: F64) -> F64:
    """``distance_at`` in numpy (its path for a map with a rotated origin)."""
    ref = copy.copy(static)
    ref.axis_aligned = False
    return ref.distance_at(xy)


def ref_foreground(det: Detector, scan: LaserScan, laser: Pose2D) -> tuple[F64, F64, F64]:
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    valid = scan.valid_mask() & (ranges <= det.cfg.max_range_m)
    idx = np.flatnonzero(valid)
    r = ranges[idx]
    ang = scan.angle_min_rad + idx * scan.angle_increment_rad + laser.yaw
    pts = np.column_stack([laser.x + r * np.cos(ang), laser.y + r * np.sin(ang)])
    keep = ref_distance_at(det.static, pts) > det.cfg.static_margin_m
    return idx[keep], pts[keep], r[keep]


def ref_start_after_a_split(idx: F64, pts: F64, r: F64, n: int,
                            gap_m: float) -> tuple[F64, F64, F64]:
    step = (np.roll(idx, -1) - idx) % n
    nxt = np.roll(pts, -1, axis=0)
    gap = np.hypot(nxt[:, 0] - pts[:, 0], nxt[:, 1] - pts[:, 1])
    split = (gap > gap_m + 0.01 * np.roll(r, -1)) | (step > 3)
    if split[-1] or not split.any():
        return idx, pts, r
    k = int(np.flatnonzero(split)[-1]) + 1
    return np.roll(idx, -k), np.roll(pts, -k, axis=0), np.roll(r, -k)


def ref_segments(det: Detector, idx: F64, pts: F64, r: F64,
                 circle_beams: int = 0) -> list[tuple[float, float, float, F64]]:
    cfg = det.cfg
    if circle_beams and len(idx) > 1:
        idx, pts, r = ref_start_after_a_split(idx, pts, r, circle_beams, cfg.segment_gap_m)
    step = np.diff(idx) % circle_beams if circle_beams else np.diff(idx)
    gap = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
    split = (gap > cfg.segment_gap_m + 0.01 * r[1:]) | (step > 3)
    starts = np.concatenate([[0], np.flatnonzero(split) + 1])
    ends = np.concatenate([starts[1:], [len(idx)]])
    counts = ends - starts
    cx = np.add.reduceat(pts[:, 0], starts) / counts
    cy = np.add.reduceat(pts[:, 1], starts) / counts
    width = np.hypot(pts[ends - 1, 0] - pts[starts, 0], pts[ends - 1, 1] - pts[starts, 1])
    keep = (width <= cfg.max_width_m) & ((counts >= 2) | (r[starts] >= 3.0))
    return [(float(cx[k]), float(cy[k]), max(float(width[k]), 0.05),
             idx[starts[k]:ends[k]]) for k in np.flatnonzero(keep).tolist()
            if width[k] <= 0.45 or not _flat(pts[starts[k]:ends[k]])]


class EveryPair(Detector):
    """The detector that measures every pair of legs (what ``_close_pairs`` narrows down)."""

    def _close_pairs(self, pushed: list[tuple[float, float, float, F64]],
                     legs: list[int]) -> list[tuple[float, int, int]]:
        return [(math.hypot(pushed[a][0] - pushed[b][0], pushed[a][1] - pushed[b][1]), a, b)
                for i, a in enumerate(legs) for b in legs[i + 1:]]


def ref_people(det: Detector, segments: list[tuple[float, float, float, F64]],
               sensor: tuple[float, float]) -> list[Detection]:
    return EveryPair(det.cfg, det.static)._people(segments, sensor)


def as_tuples(dets: list[Detection]) -> list[tuple[object, ...]]:
    return [(d.x_m, d.y_m, d.width_m, d.beams) for d in dets]


# -- the detector ------------------------------------------------------------------------------
def random_scans(grid: OccupancyGrid, count: int, seed: int) -> list[tuple[LaserScan, Pose2D]]:
    """Scans of ``grid`` with up to 12 random bodies and legs, from random poses; some with
    invalid and out-of-range returns, some in float64."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        laser = Pose2D(*rng.uniform(-4.0, 4.0, 2), float(rng.uniform(-math.pi, math.pi)))
        n = int(rng.integers(0, 13))
        circles = np.column_stack([rng.uniform(-6.0, 6.0, (n, 2)), rng.uniform(0.04, 0.35, n)])
        s = scan_of(grid, circles, laser, seed=k)
        r = np.array(s.ranges_m, dtype=np.float32 if k % 2 else np.float64)
        r[rng.random(len(r)) < 0.03] = np.nan
        r[rng.random(len(r)) < 0.02] = 0.05
        out.append((LaserScan(0.0, s.angle_min_rad, s.angle_increment_rad, s.range_min_m,
                              s.range_max_m, r), laser))
    return out


@pytest.mark.parametrize("yaw", [0.0, 0.3])
def test_the_detector_matches_its_numpy_formulas(cfg: Config, yaw: float) -> None:
    """foreground, segments and people, scan by scan, on a map with an unrotated origin (the
    compiled path) and a rotated one (numpy's)."""
    base = room()
    grid = OccupancyGrid(base.data, base.resolution_m, Pose2D(-7.0, -7.0, yaw))
    det = Detector(cfg.people, StaticMap(grid))
    assert det.static.axis_aligned == (yaw == 0.0)
    people = 0
    for scan, laser in random_scans(grid, 60, seed=int(yaw * 10)):
        fg = det.foreground(scan, laser)
        assert same(list(fg), list(ref_foreground(det, scan, laser)))
        idx, pts, r = fg
        if not len(idx):
            continue
        for circle in (len(scan.ranges_m), 0):
            segments = det._segments(idx, pts, r, circle)
            assert same(segments, ref_segments(det, idx, pts, r, circle))
        found = det._people(segments, (laser.x, laser.y))
        assert same(as_tuples(found), as_tuples(ref_people(det, segments, (laser.x, laser.y))))
        people += len(found)
    assert people > 100


def test_the_map_lookup_matches_numpy(cfg: Config) -> None:
    """The distance field at random points, inside and outside the map, and on cell edges."""
    rng = np.random.default_rng(3)
    for origin in (Pose2D(-7.0, -7.0, 0.0), Pose2D(0.0, 0.0, 0.0), Pose2D(-3.3, 1.7, -0.0)):
        base = room()
        static = StaticMap(OccupancyGrid(base.data, base.resolution_m, origin))
        assert static.axis_aligned
        xy = np.concatenate([rng.uniform(-12.0, 12.0, (5000, 2)),
                             np.round(rng.uniform(-8.0, 8.0, (2000, 2)), 2),
                             [[0.0, 0.0], [-0.0, -0.0], [origin.x, origin.y]]])
        assert same(static.distance_at(xy), ref_distance_at(static, xy))


def random_segments(rng: np.random.Generator, n_beams: int) -> tuple[F64, F64, F64]:
    """Returns in beam order: runs of neighbouring beams (some across the seam) with points a
    few centimetres apart, scattered returns, and long runs (a wall)."""
    idx = np.flatnonzero(rng.random(n_beams) < rng.uniform(0.05, 0.9))
    if rng.random() < 0.3:
        idx = np.arange(n_beams)[(np.arange(n_beams) + int(rng.integers(n_beams))) % n_beams
                                 < int(rng.integers(1, n_beams))]
    steps = rng.normal(0.0, rng.uniform(0.005, 0.2), (len(idx), 2))
    pts = rng.uniform(-5.0, 5.0, 2) + np.cumsum(steps, axis=0)
    r = rng.uniform(0.2, 8.0, len(idx))
    return idx.astype(np.int64), pts, r


def test_segments_match_numpy_on_random_returns(cfg: Config) -> None:
    """Segments of random returns (full-circle scans, partial ones, the seam) and the people
    made of them."""
    det = Detector(cfg.people, StaticMap(room()))
    rng = np.random.default_rng(11)
    for _ in range(400):
        idx, pts, r = random_segments(rng, int(rng.choice([360, 720, 100])))
        if not len(idx):
            continue
        for circle in (0, int(idx.max()) + 1):
            segments = det._segments(idx, pts, r, circle)
            assert same(segments, ref_segments(det, idx, pts, r, circle))
            sensor = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)))
            assert same(as_tuples(det._people(segments, sensor)),
                        as_tuples(ref_people(det, segments, sensor)))


def test_crowded_legs_pair_as_with_every_pair(cfg: Config) -> None:
    """Many leg-sized segments close together: only the pairs near along x and y are measured,
    and the pairing is the one that measured them all."""
    det = Detector(cfg.people, StaticMap(room()))
    rng = np.random.default_rng(5)
    for _ in range(300):
        n = int(rng.integers(0, 40))
        segments = [(float(x), float(y), float(w), np.array([k], dtype=np.int64))
                    for k, (x, y, w) in enumerate(zip(rng.uniform(-2, 2, n), rng.uniform(-2, 2, n),
                                                      rng.uniform(0.05, 0.4, n), strict=True))]
        assert same(as_tuples(det._people(segments, (0.0, 0.0))),
                    as_tuples(ref_people(det, segments, (0.0, 0.0))))


def test_pairwise_sum_is_numpys_reduction() -> None:
    """Runs of 0 to 400 elements of a strided column summed as ``np.add.reduceat`` does."""
    rng = np.random.default_rng(2)
    pts = rng.normal(0.0, 1.0, (1000, 2)) * np.exp(rng.uniform(-5.0, 5.0, (1000, 2)))
    for n in [*range(1, 140), 255, 256, 257, 300, 399, 400]:
        start = int(rng.integers(0, 1000 - n))
        for col in (0, 1):
            want = np.add.reduceat(pts[:, col], [start, start + n])[0]
            got = pts[start, col] + pairwise_sum(pts, start + 1, n - 1, col)
            assert same(float(got), float(want)), (n, col)


# -- the tracker's filter ----------------------------------------------------------------------
def new_filter(x: float, y: float, sig: float) -> KalmanFilter:
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.x = np.array([[x], [y], [0.0], [0.0]])
    kf.P = np.diag([sig * sig, sig * sig, 1.0, 1.0])
    kf.H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    kf.R = np.eye(2) * sig * sig
    return kf


def test_predict_and_update_are_filterpys() -> None:
    """Long random histories (steps of 0.1 s and others, missed scans, jumps): the state and
    covariance after each predict and each update equal filterpy's."""
    rng = np.random.default_rng(9)
    sig = 0.06
    for _ in range(400):
        x0, y0 = rng.uniform(-30.0, 30.0, 2)
        ref, ours = new_filter(x0, y0, sig), new_filter(x0, y0, sig)
        vx, vy = rng.normal(0.0, 1.2, 2)
        t = 0.0
        for _ in range(40):
            dt = round(float(rng.choice([0.1, 0.1, 0.2, 0.3, 0.0999, 0.05])), 4)
            f = np.eye(4)
            f[0, 2] = f[1, 3] = dt
            q = Q_discrete_white_noise(2, dt=dt, var=4.0, block_size=2, order_by_dim=False)
            ref.F, ref.Q = f, q
            ref.predict()
            _predict(ours, f, q)
            assert same(ours.x, ref.x) and same(ours.P, ref.P)
            t += dt
            if rng.random() < 0.8:
                zx = float(x0 + vx * t + rng.normal(0.0, rng.choice([0.03, 0.5])))
                zy = float(y0 + vy * t + rng.normal(0.0, 0.05))
                ref.update(np.array([[zx], [zy]]))
                _update(ours, zx, zy)
                assert same(ours.x, ref.x) and same(ours.P, ref.P)


def test_a_filter_without_the_trackers_structure_gets_filterpys_update() -> None:
    """x–y covariance, or a measurement matrix that is not a selection: filterpy's own."""
    for kind in ("P", "H"):
        ref, ours = new_filter(1.0, 2.0, 0.1), new_filter(1.0, 2.0, 0.1)
        for kf in (ref, ours):
            if kind == "P":
                kf.P[0, 1] = kf.P[1, 0] = 0.001
            else:
                kf.H = np.array([[1.0, 0.0, 0.1, 0.0], [0.0, 1.0, 0.0, 0.0]])
        ref.update(np.array([[1.3], [1.9]]))
        _update(ours, 1.3, 1.9)
        assert same(ours.x, ref.x) and same(ours.P, ref.P)
        assert ours.K is not None and ours.K.shape == (4, 2)  # filterpy's bookkeeping ran


# -- the node ----------------------------------------------------------------------------------
def test_beams_near_people_match_numpy() -> None:
    """The localiser's beams on people: end points near predicted people, as numpy compares
    them (NaN and infinite returns never count; end points right at the reach too)."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        n = 360
        ranges = rng.uniform(0.0, 10.0, n)
        ranges[rng.random(n) < 0.05] = np.nan
        ranges[rng.random(n) < 0.05] = np.inf
        valid = np.isfinite(ranges) & (ranges >= 0.15)
        x, y, yaw = (*rng.uniform(-5.0, 5.0, 2), float(rng.uniform(-4.0, 4.0)))
        ang = yaw + (-math.pi + np.arange(n) * (2.0 * math.pi / n))
        reach = 0.25 + 0.15
        with np.errstate(invalid="ignore"):
            ex = x + ranges * np.cos(ang)
            ey = y + ranges * np.sin(ang)
        # Some people anywhere, some right at the reach of an end point: whether that beam
        # counts is decided by the last bit of the squared distance.
        ends = rng.choice(np.flatnonzero(valid), 20)
        side = rng.uniform(-math.pi, math.pi, 20)
        people = np.concatenate([
            rng.uniform(-8.0, 8.0, (int(rng.integers(1, 8)), 2)),
            np.column_stack([ex[ends] + reach * np.cos(side), ey[ends] + reach * np.sin(side)])])
        near = np.zeros(n, dtype=bool)
        for px, py in people:
            near |= (ex - px) ** 2 + (ey - py) ** 2 <= reach * reach
        want = valid & near
        got, found = beams_near(valid, ranges, np.cos(ang), np.sin(ang), x, y, people,
                                reach * reach)
        assert same(got, want) and found == bool(want.any())
