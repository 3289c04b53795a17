"""The compiled collision check gives the numpy expression's costs bit for bit."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.nav.controller import LocalController
from curio.nav.costs import LETHAL
from curio.robot import RobotModel


@dataclass
class _Grid:
    grid: npt.NDArray[np.uint8]
    resolution_m: float
    origin: Pose2D
    footprint: npt.NDArray[np.float64]

    def costs(self) -> npt.NDArray[np.uint8]:
        return self.grid


def _reference(ctl: LocalController, trajs: npt.NDArray[np.float64],
               coarse: bool = False) -> npt.NDArray[np.uint8]:
    """The numpy implementation the kernel replaced."""
    cm = ctl.costmap
    assert cm is not None
    grid = cm.costs()
    res = float(cm.resolution_m)
    origin = cm.origin
    per = ctl._perimeter(cm)
    if coarse:
        per = per[::2]
    x = trajs[..., 0:1]
    y = trajs[..., 1:2]
    c, s = np.cos(trajs[..., 2:3]), np.sin(trajs[..., 2:3])
    px = x + c * per[:, 0] - s * per[:, 1]
    py = y + s * per[:, 0] + c * per[:, 1]
    if origin.yaw != 0.0:
        oc, os_ = math.cos(origin.yaw), math.sin(origin.yaw)
        gx = oc * (px - origin.x) + os_ * (py - origin.y)
        gy = -os_ * (px - origin.x) + oc * (py - origin.y)
    else:
        gx, gy = px - origin.x, py - origin.y
    with np.errstate(invalid="ignore"):
        cols = np.floor(gx / res).astype(np.int64)
        rows = np.floor(gy / res).astype(np.int64)
    h, w = grid.shape
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    vals = np.full(rows.shape, LETHAL, dtype=np.uint8)
    vals[inside] = grid[rows[inside], cols[inside]]
    return np.asarray(vals.max(axis=2), dtype=np.uint8)


@pytest.mark.parametrize("yaw", [0.0, 0.3])
def test_trajectory_costs_match_numpy(cfg: Config, yaw: float) -> None:
    rng = np.random.default_rng(7)
    robot = RobotModel.from_config(cfg.robot)
    fp = np.array([[0.3, 0.2], [-0.25, 0.2], [-0.25, -0.2], [0.3, -0.2]])
    grid = rng.integers(0, 256, size=(60, 80)).astype(np.uint8)
    cm = _Grid(grid, 0.05, Pose2D(-2.0, -1.5, yaw), fp)
    ctl = LocalController(cfg.nav.controller, robot, cm)  # type: ignore[arg-type]
    for m, k in [(1, 31), (33, 31), (5, 1)]:
        trajs = np.empty((m, k, 3))
        trajs[..., 0] = rng.uniform(-2.6, 2.6, (m, k))  # partly off the grid
        trajs[..., 1] = rng.uniform(-2.0, 2.0, (m, k))
        trajs[..., 2] = rng.uniform(-4.0, 4.0, (m, k))
        for coarse in (False, True):
            got = ctl.trajectory_costs(trajs, coarse=coarse)
            assert got.dtype == np.uint8
            np.testing.assert_array_equal(got, _reference(ctl, trajs, coarse))
        # A strided view, as the people stage passes.
        view = trajs[:, : max(1, k // 2)]
        np.testing.assert_array_equal(ctl.trajectory_costs(view), _reference(ctl, view))
    # Poses exactly on cell edges, and non-finite ones (off the grid: lethal).
    trajs = np.zeros((1, 6, 3))
    trajs[0, :, 0] = [-2.0, 0.0, 1.95, np.nan, np.inf, -np.inf]
    trajs[0, :, 1] = [-1.5, 0.0, 1.45, 0.0, 0.0, 0.0]
    np.testing.assert_array_equal(ctl.trajectory_costs(trajs), _reference(ctl, trajs))
    assert (ctl.trajectory_costs(trajs)[0, 3:] == LETHAL).all()
