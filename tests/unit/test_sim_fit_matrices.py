"""The rigid-motion fit's normal matrix keeps numpy's bits when accumulated on Python floats."""

from __future__ import annotations

import math

import numpy as np

from curio.drivers.kinematics import STEER_CORNERS
from curio.sim.world import _fit_matrices


def _reference(
    xs: tuple[float, ...], ys: tuple[float, ...], steer: tuple[float, ...]
) -> tuple[list[tuple[float, float, float]], list[list[float]]]:
    """The former numpy accumulation (``np.outer`` on 3-vectors)."""
    angles = [0.0] * 6
    for k, i in enumerate(STEER_CORNERS):
        angles[i] = steer[k]
    rows: list[tuple[float, float, float]] = []
    ata = np.zeros((3, 3))
    for i in range(6):
        c, s = math.cos(angles[i]), math.sin(angles[i])
        x, y = xs[i], ys[i]
        roll = (c, s, -c * y + s * x)
        side = (-s, c, s * y + c * x)
        rows.append(roll)
        ata += np.outer(roll, roll) + np.outer(side, side)
    inv = np.linalg.inv(ata)
    return rows, [[float(v) for v in row] for row in inv]


def test_fit_matrices_bit_identical_to_numpy_accumulation() -> None:
    rng = np.random.default_rng(7)
    xs = (0.3, 0.0, -0.3, 0.3, 0.0, -0.3)
    ys = (0.25, 0.28, 0.25, -0.25, -0.28, -0.25)
    cases: list[tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]] = [
        (xs, ys, (0.0, 0.0, 0.0, 0.0))]
    for _ in range(300):
        gx = tuple(float(v) for v in rng.uniform(-0.5, 0.5, 6))
        gy = tuple(float(v) for v in rng.uniform(-0.5, 0.5, 6))
        steer = tuple(float(v) for v in rng.uniform(-1.2, 1.2, 4))
        cases.append((gx, gy, steer))
        cases.append((xs, ys, steer))
    for case in cases:
        rows, inv = _fit_matrices(*case)
        ref_rows, ref_inv = _reference(*case)
        assert rows == ref_rows
        assert np.array(inv).tobytes() == np.array(ref_inv).tobytes()
