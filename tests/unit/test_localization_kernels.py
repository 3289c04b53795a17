"""The localiser's compiled lookups give the numpy expressions' results to the last bit.

The reference is the numpy code the kernels replaced, which the localiser keeps for maps with a
rotated origin; points inside, on the edges, outside the grid and NaN are compared bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.estimation.localization import DistanceField, _MatchTerms, scan_match
from tests.unit.test_localization_helpers import room_grid

F64 = np.ndarray


def _numpy_path(f: DistanceField, name: str, *args: F64) -> object:
    """The numpy code the kernels replaced, kept for rotated grids: forced on this unrotated
    one (its zero rotation is exact: x + 1·x' − 0·y' and the gradient's rotation change
    nothing)."""
    f._rotated = True
    try:
        with np.errstate(invalid="ignore"):
            return getattr(f, name)(*args)
    finally:
        f._rotated = False


def _ref_lookup(f: DistanceField, x: F64, y: F64) -> F64:
    out = _numpy_path(f, "lookup", x, y)
    assert isinstance(out, np.ndarray)
    return out


def _ref_lookup_grad(f: DistanceField, x: F64, y: F64) -> tuple[F64, F64, F64]:
    out = _numpy_path(f, "lookup_grad", x, y)
    assert isinstance(out, tuple)
    return out


@pytest.fixture(scope="module")
def field() -> DistanceField:
    return DistanceField(room_grid(), 2.0)


def _points(rng: np.random.Generator, n: int) -> tuple[F64, F64]:
    """Map points over the grid and a margin around it, some exactly on cell edges, some NaN."""
    x = rng.uniform(-2.0, 12.0, n)
    y = rng.uniform(-2.0, 8.0, n)
    x[: n // 10] = np.round(x[: n // 10] / 0.05) * 0.05  # on edges
    x[-3:] = np.nan
    return x, y


def test_lookups_equal_the_numpy_expressions(field: DistanceField) -> None:
    x, y = _points(np.random.default_rng(1), 20_000)
    assert np.array_equal(field.lookup(x, y), _ref_lookup(field, x, y))
    for got, ref in zip(field.lookup_grad(x, y), _ref_lookup_grad(field, x, y), strict=True):
        assert np.array_equal(got, ref, equal_nan=True)
    # Any shape, as before.
    grid = field.lookup(x[:600].reshape(20, 30), y[:600].reshape(20, 30))
    assert grid.shape == (20, 30)
    assert np.array_equal(grid.ravel(), _ref_lookup(field, x[:600], y[:600]))


def test_lookup_poses_equals_the_broadcast_expression(field: DistanceField) -> None:
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(0, 10, 50), rng.uniform(0, 6, 50),
                             rng.uniform(-math.pi, math.pi, 50)])
    pts = rng.uniform(-4.0, 4.0, (90, 2))
    c = np.cos(poses[:, 2])[:, None]
    s = np.sin(poses[:, 2])[:, None]
    wx = poses[:, 0:1] + c * pts[None, :, 0] - s * pts[None, :, 1]
    wy = poses[:, 1:2] + s * pts[None, :, 0] + c * pts[None, :, 1]
    assert np.array_equal(field.lookup_poses(poses, pts), _ref_lookup(field, wx, wy))


def test_match_terms_equal_the_numpy_path(field: DistanceField) -> None:
    """The compiled scan-match terms and the numpy fallback (rotated grids) agree bit for
    bit, and so does a whole scan match."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5.0, 5.0, (180, 2))
    terms = _MatchTerms(field, pts[:, 0], pts[:, 1], 0.025, 0.15)
    for _ in range(50):
        x, y, th = rng.uniform(1, 9), rng.uniform(1, 6), rng.uniform(-math.pi, math.pi)
        c, s = math.cos(th), math.sin(th)
        got, ref = terms.at(x, y, c, s), terms._numpy(x, y, c, s)
        assert (got is None) == (ref is None)
        if got is not None and ref is not None:
            for a, b in zip(got, ref, strict=True):
                assert np.array_equal(a, b)
    guess = Pose2D(3.0, 4.0, 0.3)
    compiled = scan_match(field, pts, guess)
    field._rotated = True  # the numpy path (to_local with a zero rotation is exact)
    try:
        plain = scan_match(field, pts, guess)
    finally:
        field._rotated = False
    assert compiled.pose == plain.pose
    assert np.array_equal(compiled.covariance, plain.covariance)
    assert compiled.inlier_fraction == plain.inlier_fraction



def _ref_heaviest_bin(p: F64, w: F64) -> F64:
    """The numpy code ``heaviest_bin`` replaced in ``Localizer._cluster``."""
    key = (np.floor(p[:, 0] / 0.5).astype(np.int64) * 100_003
           + np.floor(p[:, 1] / 0.5).astype(np.int64))
    uniq, inv = np.unique(key, return_inverse=True)
    mass = np.bincount(inv, weights=w, minlength=len(uniq))
    out: F64 = inv == int(np.argmax(mass))
    return out


def test_heaviest_bin_equals_unique_bincount_argmax() -> None:
    from curio.estimation.localization_kernels import heaviest_bin

    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 200, 1000):
        p = np.column_stack([rng.normal(0.0, 0.7, n), rng.normal(-3.0, 0.7, n),
                             rng.uniform(-math.pi, math.pi, n)])
        p[: n // 4, :2] = np.round(p[: n // 4, :2] * 2.0) / 2.0  # on bin edges
        for w in (rng.random(n), np.full(n, 1.0 / n), np.zeros(n)):  # ties: the smallest key
            sel = np.empty(n, dtype=np.bool_)
            heaviest_bin(p, w, 0.5, sel)
            assert np.array_equal(sel, _ref_heaviest_bin(p, w))


def test_ends_local_equals_world_then_to_local(field: DistanceField) -> None:
    from curio.estimation.localization import Localizer
    from curio.estimation.localization_kernels import ends_local

    rng = np.random.default_rng(4)
    pts = rng.uniform(-6.0, 6.0, (181, 2))
    for pose in (Pose2D(1.3, -0.7, 0.3), Pose2D(-2.0, 4.1, -2.9), Pose2D(0.1, 0.2, math.pi)):
        ex, ey = np.empty(len(pts)), np.empty(len(pts))
        ends_local(pose.x, pose.y, math.cos(pose.yaw), math.sin(pose.yaw), pts,
                   field.origin.x, field.origin.y, ex, ey)
        rx, ry = field.to_local(*Localizer._world(pts, pose))
        assert ex.tobytes() == rx.tobytes() and ey.tobytes() == ry.tobytes()
