"""The planner benchmark's own parts: map generator, pair sampler, the heapq A* peer."""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy import ndimage

from benchmarks.bench_planner import (
    MIN_PAIR_DISTANCE_M,
    cell_path_length_m,
    generate_map,
    heapq_astar,
    sample_pairs,
)
from curio.core.config import PlannerConfig
from curio.core.geometry import Pose2D
from curio.nav.planner import GlobalPlanner, traversal_lut


def test_generated_map_is_deterministic_with_the_wanted_obstacle_fraction() -> None:
    a = generate_map(5, size=300)
    b = generate_map(5, size=300)
    c = generate_map(6, size=300)
    assert np.array_equal(a.data, b.data)
    assert not np.array_equal(a.data, c.data)
    frac = float(a.occupied_mask().mean())
    assert 0.20 <= frac < 0.23
    assert a.resolution_m == 0.05 and a.data.shape == (300, 300)


def test_pairs_are_free_connected_and_far_apart() -> None:
    grid = generate_map(2, size=300)
    free = ~ndimage.binary_dilation(grid.occupied_mask(), iterations=6)
    pairs = sample_pairs(free, 0.05, 20, seed=3)
    assert len(pairs) == 20
    assert pairs == sample_pairs(free, 0.05, 20, seed=3)
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    region = {int(labels[s]) for s, _ in pairs} | {int(labels[g]) for _, g in pairs}
    assert len(region) == 1 and 0 not in region
    for s, g in pairs:
        assert math.dist(s, g) * 0.05 > MIN_PAIR_DISTANCE_M


def test_heapq_peer_finds_the_same_optimum_as_curio() -> None:
    rng = np.random.default_rng(0)
    costs = rng.integers(0, 120, size=(40, 40)).astype(np.uint8)
    costs[10:30, 20] = 254  # the optimum passes the wall's end: no corner may be cut
    costs[rng.random((40, 40)) < 0.1] = 254
    costs[5, 5] = costs[35, 35] = 0
    lut = traversal_lut(3.0, False)
    cells = heapq_astar(lut[costs], (5, 5), (35, 35))
    assert cells is not None and cells[0] == (5, 5) and cells[-1] == (35, 35)
    cost = sum(math.dist(a, b) * 0.5 * (lut[costs[a]] + lut[costs[b]])
               for a, b in itertools.pairwise(cells))
    res = GlobalPlanner(PlannerConfig(heuristic_weight=1.0, smooth=False)).plan_detailed(
        Pose2D(0.275, 0.275), Pose2D(1.775, 1.775), costs, 0.05, Pose2D())
    assert abs(res.cost - cost) <= 1e-3 * cost
    assert cell_path_length_m(np.asarray(cells), 0.05) > 0.0
    blocked = costs.copy()
    blocked[20, :] = 254
    assert heapq_astar(lut[blocked], (5, 5), (35, 35)) is None
