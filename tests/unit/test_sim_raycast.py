"""Ray casting against hand-computed geometry: walls, boxes, doors, people."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid
from curio.sim.objects import Door, Person
from curio.sim.raycast import GridRaycaster, cast_circles, cast_segments, naive_cast
from curio.sim.world import World, WorldSpec

RES = 0.05


def room(width_m: float = 6.0, height_m: float = 4.0) -> OccupancyGrid:
    """A closed room: the free interior spans x 0..width, y 0..height (walls 0.1 m outside)."""
    w, h = round(width_m / RES) + 4, round(height_m / RES) + 4
    data = np.zeros((h, w), dtype=np.int8)
    data[:2, :] = data[-2:, :] = 100
    data[:, :2] = data[:, -2:] = 100
    return OccupancyGrid(data, RES, Pose2D(-0.1, -0.1, 0.0))


def quiet_config() -> Config:
    cfg = Config()
    noise = cfg.sim.noise
    noise.lidar_range_sigma_m = 0.0
    noise.lidar_dropout_fraction = 0.0
    noise.lidar_invalid_fraction = 0.0
    return cfg


def test_walls_at_known_distances() -> None:
    rc = GridRaycaster(room())
    angles = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2, math.atan2(2.0, 3.0)])
    r = rc.cast(1.0, 1.0, angles, 12.0)
    # Walls' inner faces at x = 0, x = 6, y = 0, y = 4.
    assert r[:4] == pytest.approx([5.0, 3.0, 1.0, 1.0], abs=1e-6)
    # Up 3 m to the top wall while moving 4.5 m in x (x = 5.5 < 6).
    assert r[4] == pytest.approx(math.hypot(4.5, 3.0), abs=1e-6)


def test_grazing_and_max_range() -> None:
    rc = GridRaycaster(room(20.0, 4.0))
    # Almost parallel to the bottom wall from 0.3 m above it: hits the far wall or the floor wall.
    a = math.radians(-0.5)
    r = rc.cast(0.5, 0.3, np.array([a]), 30.0)[0]
    want = min(19.5 / math.cos(a), 0.3 / math.sin(-a))
    assert r == pytest.approx(want, abs=0.01)
    assert np.isinf(rc.cast(0.5, 0.3, np.array([0.0]), 12.0)[0])  # wall at 19.5 m > 12 m


def test_agrees_with_naive_peer() -> None:
    grid = room(8.0, 5.0)
    grid.data[40:60, 60:70] = 100  # a pillar
    rc = GridRaycaster(grid)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    fast = rc.cast(2.0, 1.5, angles, 12.0)
    slow = naive_cast(grid, 2.0, 1.5, angles, 12.0)
    assert np.all(np.isfinite(fast) == np.isfinite(slow))
    fin = np.isfinite(fast)
    diff = fast[fin] - slow[fin]
    # The half-cell stepping peer can step over a clipped corner; the exact caster cannot.
    assert np.all(diff <= 1e-9)
    assert np.mean(np.abs(diff) <= 0.5 * RES + 1e-9) >= 0.98
    # Beam at 57° clips the pillar's corner (x 2.9, y 2.886 < 2.9): exact range 0.9 / cos 57°.
    i = int(np.argmin(np.abs(angles - math.radians(57.0))))
    assert fast[i] == pytest.approx(0.9 / math.cos(angles[i]), abs=1e-6)


def test_segments_and_circles_analytic() -> None:
    dx, dy = np.array([1.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    segs = np.array([[2.0, -1.0, 2.0, 1.0]])  # vertical segment at x = 2
    assert cast_segments(0.0, 0.0, dx, dy, segs)[0] == pytest.approx(2.0)
    assert np.isinf(cast_segments(0.0, 0.0, dx, dy, segs)[1:]).all()
    circles = np.array([[0.0, 3.0, 0.5]])
    assert cast_circles(0.0, 0.0, dx, dy, circles)[1] == pytest.approx(2.5)
    assert np.isinf(cast_circles(0.0, 0.0, dx, dy, circles)[[0, 2]]).all()


def _world(spec: WorldSpec | None = None) -> World:
    # Rover at x 1 facing +x: the laser sits at (1.152, 1.078) in map.
    return World(room(), quiet_config(), Pose2D(1.0, 1.0, 0.0), spec)


def test_scan_frame_and_box() -> None:
    w = _world()
    scan = w.cast_scan(2.0)
    assert scan.stamp == 2.0 and scan.frame_id == "laser"
    assert len(scan.ranges_m) == 360
    ahead = round((0.0 - scan.angle_min_rad) / scan.angle_increment_rad)
    assert scan.ranges_m[ahead] == pytest.approx(6.0 - 1.152, abs=1e-4)
    box = w.add_box(3.5, 1.078, 1.0, 1.0)
    assert w.cast_scan(2.1).ranges_m[ahead] == pytest.approx(3.0 - 1.152, abs=1e-4)
    w.remove_object(box)
    assert w.cast_scan(2.2).ranges_m[ahead] == pytest.approx(6.0 - 1.152, abs=1e-4)


def test_door_closed_and_open() -> None:
    door = Door("d", (4.0, 0.0), (4.0, 4.0), is_open=True, thickness_m=0.1)
    w = _world(WorldSpec(doors=[door]))
    angles = np.array([0.0])
    assert w.cast_ranges(angles, 12.0)[0] == pytest.approx(6.0 - 1.152, abs=1e-4)
    w.set_door("d", False)
    assert w.cast_ranges(angles, 12.0)[0] == pytest.approx(3.95 - 1.152, abs=1e-4)
    w.set_door("d", True)
    assert w.cast_ranges(angles, 12.0)[0] == pytest.approx(6.0 - 1.152, abs=1e-4)
    with pytest.raises(KeyError, match="doors: \\['d'\\]"):
        w.set_door("nope", True)


def test_person_seen_by_lidar() -> None:
    w = _world(WorldSpec(people=[Person([(4.152, 1.078)], speed_mps=0.0, radius_m=0.3)]))
    assert w.cast_ranges(np.array([0.0]), 12.0)[0] == pytest.approx(3.0 - 0.3, abs=1e-4)


def test_noise_dropouts_and_invalid_returns() -> None:
    cfg = Config()
    cfg.sim.noise.lidar_dropout_fraction = 0.2
    cfg.sim.noise.lidar_invalid_fraction = 0.1
    w = World(room(), cfg, Pose2D(1.0, 1.0, 0.0))
    r = w.cast_scan(0.0).ranges_m
    n_inf, n_nan = int(np.isinf(r).sum()), int(np.isnan(r).sum())
    assert 40 <= n_inf <= 110 and 15 <= n_nan <= 60
    fin = np.isfinite(r)
    clean = World(room(), quiet_config(), Pose2D(1.0, 1.0, 0.0)).cast_scan(0.0).ranges_m
    err = r[fin] - clean[fin]
    assert 0.005 < float(np.std(err)) < 0.04  # σ = 0.02 m


def test_same_seed_same_scan_other_seed_differs() -> None:
    a = World(room(), Config(), Pose2D(1.0, 1.0, 0.3)).cast_scan(0.0).ranges_m
    b = World(room(), Config(), Pose2D(1.0, 1.0, 0.3)).cast_scan(0.0).ranges_m
    np.testing.assert_array_equal(a, b)
    cfg = Config()
    cfg.sim.seed = 2
    c = World(room(), cfg, Pose2D(1.0, 1.0, 0.3)).cast_scan(0.0).ranges_m
    assert not np.array_equal(np.nan_to_num(a, posinf=99), np.nan_to_num(c, posinf=99))


def test_numpy_backend_agrees_with_compiled() -> None:
    grid = room(8.0, 5.0)
    grid.data[40:60, 60:70] = 100
    grid.data[80:85, 20:140] = 100
    exact = GridRaycaster(grid, backend="compiled")
    vect = GridRaycaster(grid, backend="numpy")
    rng = np.random.default_rng(3)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    same = total = 0
    for _ in range(20):
        x, y = rng.uniform(0.2, 7.8), rng.uniform(0.2, 4.8)
        if exact.occupied_at(np.array([[x, y]]))[0]:
            continue
        a = exact.cast(x, y, angles, 12.0)
        b = vect.cast(x, y, angles, 12.0)
        fa, fb = np.nan_to_num(a, posinf=1e3), np.nan_to_num(b, posinf=1e3)
        # The numpy backend samples every half cell: it can only miss a clipped corner
        # (a later hit), never invent an earlier one.
        assert np.all(fa <= fb + 1e-9)
        same += int(np.sum(np.abs(fa - fb) <= 1e-6))
        total += len(angles)
    assert same / total >= 0.97


def test_bad_backend_named() -> None:
    with pytest.raises(ValueError, match="compiled' or 'numpy'"):
        GridRaycaster(room(), backend="gpu")
