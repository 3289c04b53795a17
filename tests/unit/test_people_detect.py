"""The people detector on single scans: a person across the scan's seam is one person, a flat
panel the map does not show (a closed door, a board) is nobody, a wide body still is someone."""

from __future__ import annotations

import math

import numpy as np

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan
from curio.estimation.maps import OccupancyGrid
from curio.people.detect import Detection, Detector, StaticMap
from curio.sim.raycast import GridRaycaster, cast_circles
from tests.unit.test_people_tracker import BEAMS, INC, room


def scan(grid: OccupancyGrid, circles: np.ndarray, laser: Pose2D = Pose2D(),
         seed: int = 1) -> LaserScan:
    """A 360-beam scan from ``laser`` (map) of ``grid`` and round bodies ``circles``
    (``(N, 3)``: x, y, radius, metres), 2 cm range noise."""
    ang = -math.pi + np.arange(BEAMS) * INC + laser.yaw
    r = GridRaycaster(grid).cast(laser.x, laser.y, ang, 12.0)
    if len(circles):
        r = np.minimum(r, cast_circles(laser.x, laser.y, np.cos(ang), np.sin(ang), circles))
    r = r + np.random.default_rng(seed).normal(0.0, 0.02, BEAMS)
    r[~np.isfinite(r) | (r > 12.0)] = np.inf
    return LaserScan(0.0, -math.pi, INC, 0.15, 12.0, r.astype(np.float32))


def near(dets: list[Detection], x: float, y: float, within_m: float = 0.5) -> list[Detection]:
    return [d for d in dets if math.hypot(d.x_m - x, d.y_m - y) < within_m]


def test_a_person_across_the_scans_seam_is_one_person(cfg: Config) -> None:
    """The first and last beams of a full-circle scan are neighbours: a wide body right behind
    the sensor (where the beam angles wrap from +π to −π) is one detection, not two halves."""
    grid = room()
    det = Detector(cfg.people, StaticMap(grid))
    for seed in range(5):
        dets = det.detect(scan(grid, np.array([[-3.0, 0.0, 0.3]]), seed=seed), Pose2D())
        found = near(dets, -3.0, 0.0)
        assert len(found) == 1, [(d.x_m, d.y_m, d.width_m) for d in found]
        assert math.hypot(found[0].x_m + 3.0, found[0].y_m) < 0.15


def test_a_flat_panel_is_nobody_and_a_wide_body_is_someone(cfg: Config) -> None:
    """A 0.7 m board standing in the room (not on the map) is as narrow as a person with a bag
    but flat: no detection; a body as wide (0.3 m radius) is still detected."""
    grid = room()
    det = Detector(cfg.people, StaticMap(grid))
    with_board = OccupancyGrid(grid.data.copy(), grid.resolution_m, grid.origin)
    res = grid.resolution_m
    col = int((3.0 - grid.origin.x) / res)
    rows = slice(int((-0.35 - grid.origin.y) / res), int((0.35 - grid.origin.y) / res))
    with_board.data[rows, col] = 100
    for seed in range(5):
        assert not near(det.detect(scan(with_board, np.zeros((0, 3)), seed=seed), Pose2D()),
                        3.0, 0.0)
        dets = det.detect(scan(grid, np.array([[3.0, 0.0, 0.3]]), seed=seed), Pose2D())
        assert len(near(dets, 3.0, 0.0)) == 1
