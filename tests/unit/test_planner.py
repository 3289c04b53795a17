"""Global planner: optimality on small grids, clearance, smoothing, typed errors, real maps."""

from __future__ import annotations

import itertools
import math
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from curio.core.config import CostmapConfig, PlannerConfig, RobotConfig
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid, load_map
from curio.nav.api import (
    GoalBlockedError,
    GoalOutsideMapError,
    NavError,
    NoPathError,
    StartBlockedError,
    StartOutsideMapError,
)
from curio.nav.costmap import Costmap
from curio.nav.planner import GlobalPlanner, path_length_m, traversal_lut
from curio.robot import RobotModel

RES = 0.05
ORIGIN = Pose2D()


def centre(r: int, c: int, res: float = RES) -> Pose2D:
    return Pose2D((c + 0.5) * res, (r + 0.5) * res)


def raw_planner(**kw: object) -> GlobalPlanner:
    return GlobalPlanner(PlannerConfig(heuristic_weight=1.0, smooth=False, **kw))


def cells_of(poses: list[Pose2D], res: float = RES) -> np.ndarray:
    xy = np.array([[p.x, p.y] for p in poses])
    return np.floor(xy[:, ::-1] / res).astype(np.int64)


def dijkstra_cost(costs: np.ndarray, lut: np.ndarray, s: tuple[int, int],
                  g: tuple[int, int]) -> float:
    """Reference optimum with scipy's Dijkstra on the same 8-connected cost model."""
    h, w = costs.shape
    cw = lut[costs]
    idx = np.arange(h * w).reshape(h, w)
    rows, cols, vals = [], [], []
    for dr, dc in [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]:
        r0, r1 = max(0, -dr), min(h, h - dr)
        c0, c1 = max(0, -dc), min(w, w - dc)
        a = idx[r0:r1, c0:c1]
        b = idx[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
        wa = cw[r0:r1, c0:c1]
        wb = cw[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
        ok = (wa >= 0) & (wb >= 0)
        if dr and dc:  # no corner cutting: both cells beside the diagonal step traversable
            ok &= (cw[r0 + dr:r1 + dr, c0:c1] >= 0) & (cw[r0:r1, c0 + dc:c1 + dc] >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        vals.append(math.hypot(dr, dc) * 0.5 * (wa[ok] + wb[ok]))
    graph = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(h * w, h * w)).tocsr()
    dist = dijkstra(graph, indices=s[0] * w + s[1])
    return float(dist[g[0] * w + g[1]])


# ---------------------------------------------------------------- optimality and geometry


def test_diagonal_steps_cost_sqrt2() -> None:
    costs = np.zeros((20, 20), dtype=np.uint8)
    res = raw_planner().plan_detailed(centre(2, 2), centre(12, 12), costs, RES, ORIGIN)
    assert res.cost == pytest.approx(10 * math.sqrt(2.0))
    assert len(res.grid_path) == 11
    assert res.length_m == pytest.approx(10 * math.sqrt(2.0) * RES)


def test_octile_optimum_and_straight_smoothed_path() -> None:
    costs = np.zeros((30, 30), dtype=np.uint8)
    res = raw_planner().plan_detailed(centre(2, 2), centre(12, 22), costs, RES, ORIGIN)
    assert res.cost == pytest.approx(10 * math.sqrt(2.0) + 10)
    smooth = GlobalPlanner(PlannerConfig(heuristic_weight=1.0)).plan_detailed(
        centre(2, 2), centre(12, 22), costs, RES, ORIGIN)
    # shortcutting turns the octile path into the straight line
    assert smooth.length_m == pytest.approx(math.hypot(10, 20) * RES, rel=1e-6)
    assert smooth.cost == pytest.approx(res.cost)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_astar_matches_dijkstra_optimum_on_random_grids(seed: int) -> None:
    rng = np.random.default_rng(seed)
    costs = rng.integers(0, 200, size=(40, 50)).astype(np.uint8)
    costs[rng.random((40, 50)) < 0.25] = 254
    costs[2, 2] = costs[37, 47] = 0
    lut = traversal_lut(3.0, False)
    ref = dijkstra_cost(costs, lut, (2, 2), (37, 47))
    if not math.isfinite(ref):
        with pytest.raises(NoPathError):
            raw_planner().plan(centre(2, 2), centre(37, 47), costs, RES, ORIGIN)
        return
    res = raw_planner().plan_detailed(centre(2, 2), centre(37, 47), costs, RES, ORIGIN)
    assert res.cost == pytest.approx(ref, rel=1e-3)  # 1e-4 tie-break on the heuristic
    weighted = GlobalPlanner(PlannerConfig(heuristic_weight=2.0, smooth=False)).plan_detailed(
        centre(2, 2), centre(37, 47), costs, RES, ORIGIN)
    assert ref - 1e-9 <= weighted.cost <= 2.0 * ref * 1.001


def test_path_goes_around_a_wall() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)
    costs[0:30, 20] = 254
    poses = raw_planner().plan(centre(5, 5), centre(5, 35), costs, RES, ORIGIN)
    cells = cells_of(poses)
    assert cells[:, 0].max() >= 30  # over the top of the wall
    assert np.all(costs[cells[:, 0], cells[:, 1]] < 253)


def test_path_keeps_off_walls() -> None:
    """In a 1.5 m corridor the cost-aware path runs near the middle, a blind one need not."""
    grid = OccupancyGrid(np.zeros((80, 200), dtype=np.int8), RES)
    grid.data[:10, :] = 100
    grid.data[40:, :] = 100  # free rows 10..39: 1.5 m wide
    grid.data[10:14, 100] = 100  # a small bump on the lower wall
    costs = Costmap(grid, RobotModel.from_config(RobotConfig()),
                    CostmapConfig(inflation_radius_m=1.0,
                                                       cost_scaling_factor=3.0)).costs()
    start, goal = centre(25, 10), centre(25, 190)
    aware = GlobalPlanner(PlannerConfig(heuristic_weight=1.0)).plan(start, goal, costs, RES,
                                                                     ORIGIN)
    blind = GlobalPlanner(PlannerConfig(heuristic_weight=1.0, cost_penalty=0.0)).plan(
        centre(17, 10), centre(17, 190), costs, RES, ORIGIN)
    a = cells_of(aware)
    b = cells_of(blind)
    # the aware path stays within two cells of the corridor's middle row (24.5)
    assert np.all(np.abs(a[:, 0] - 24.5) <= 2.5)
    assert costs[a[:, 0], a[:, 1]].mean() < costs[b[:, 0], b[:, 1]].mean()


def test_headings_follow_the_path_and_end_with_the_goal_heading() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)
    costs[0:30, 20] = 254
    poses = GlobalPlanner(PlannerConfig()).plan(centre(5, 5), Pose2D(1.775, 0.275, 1.0),
                                                costs, RES, ORIGIN)
    first = math.atan2(poses[1].y - poses[0].y, poses[1].x - poses[0].x)
    assert poses[0].yaw == pytest.approx(first)
    turned = 0
    for prev, p, nxt in zip(poses[:-2], poses[1:-1], poses[2:], strict=True):
        # the heading is the path's tangent (central difference) ...
        tangent = math.atan2(nxt.y - prev.y, nxt.x - prev.x)
        assert abs(math.remainder(p.yaw - tangent, 2 * math.pi)) < 1e-9
        # ... and points forward along the path
        forward = math.atan2(nxt.y - p.y, nxt.x - p.x)
        turned += abs(math.remainder(p.yaw - forward, 2 * math.pi)) > math.pi / 2
    assert turned == 0
    assert poses[-1].yaw == pytest.approx(1.0)
    assert (poses[0].x, poses[0].y) == pytest.approx((0.275, 0.275))
    assert (poses[-1].x, poses[-1].y) == pytest.approx((1.775, 0.275))


def test_goal_without_heading_keeps_the_path_direction() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)
    poses = GlobalPlanner(PlannerConfig()).plan(Pose2D(0.5, 0.5, math.nan),
                                                Pose2D(1.5, 1.5, math.nan), costs, RES, ORIGIN)
    assert all(math.isfinite(p.yaw) for p in poses)
    assert poses[-1].yaw == pytest.approx(math.pi / 4)
    assert poses[0].yaw == pytest.approx(math.pi / 4)


def test_output_spacing_follows_path_step() -> None:
    costs = np.zeros((60, 60), dtype=np.uint8)
    for step in (0.05, 0.2):
        poses = GlobalPlanner(PlannerConfig(path_step_m=step)).plan(
            centre(5, 5), centre(50, 40), costs, RES, ORIGIN)
        gaps = np.array([a.distance_to(b) for a, b in itertools.pairwise(poses)])
        assert gaps.max() <= step + 1e-9
        assert gaps.mean() > 0.7 * step


def random_map(seed: int, n: int = 200) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    data = np.zeros((n, n), dtype=np.int8)
    for _ in range(45):
        r, c = rng.integers(0, n, 2)
        h, w = rng.integers(4, 30, 2)
        data[r:r + h, c:c + w] = 100
    return OccupancyGrid(data, RES)


@pytest.mark.parametrize("seed", [3, 4])
def test_smoothed_paths_are_collision_free_and_shorter(seed: int) -> None:
    grid = random_map(seed)
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    costs = cm.costs()
    free = costs < 253
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    big = np.argwhere(labels == np.argmax(np.bincount(labels.ravel())[1:]) + 1)
    rng = np.random.default_rng(seed)
    smooth = GlobalPlanner(PlannerConfig())
    raw = GlobalPlanner(PlannerConfig(smooth=False))
    checked = 0
    for _ in range(12):
        s, g = big[rng.integers(0, len(big), 2)]
        if math.dist(s, g) < 40:
            continue
        a, b = centre(*s), centre(*g)
        poses = smooth.plan(a, b, costs, RES, ORIGIN)
        raw_poses = raw.plan(a, b, costs, RES, ORIGIN)
        # every pose, and points between poses, lie in traversable cells
        xy = np.array([[p.x, p.y] for p in poses])
        fine = np.concatenate([xy[:-1] + t * (xy[1:] - xy[:-1]) for t in np.linspace(0, 1, 5)])
        cells = np.floor(fine[:, ::-1] / RES).astype(int)
        assert np.all(costs[cells[:, 0], cells[:, 1]] < 253)
        assert path_length_m(poses) <= path_length_m(raw_poses) + 1e-9
        checked += 1
    assert checked >= 5


# ---------------------------------------------------------------- start escape


def test_start_in_inscribed_zone_drives_out_but_lethal_start_is_refused() -> None:
    grid = OccupancyGrid(np.zeros((60, 60), dtype=np.int8), RES)
    grid.data[30, 20:40] = 100
    costs = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig()).costs()
    assert costs[33, 30] == 253
    poses = GlobalPlanner(PlannerConfig()).plan(centre(33, 30), centre(50, 30), costs, RES,
                                                ORIGIN)
    assert poses[-1].distance_to(centre(50, 30)) < 1e-9
    with pytest.raises(StartBlockedError, match=r"start \(1\.5\d, 1\.5\d\) m is in an obstacle"):
        GlobalPlanner(PlannerConfig()).plan(centre(30, 30), centre(50, 30), costs, RES, ORIGIN)


# ---------------------------------------------------------------- errors and goal options


def test_every_error_has_a_clear_message() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)  # 2 m × 2 m
    costs[20, 20] = 254
    costs[5:8, 30:33] = 253
    planner = GlobalPlanner(PlannerConfig(goal_nearest_free=False))
    with pytest.raises(StartOutsideMapError,
                       match=r"start \(-1\.00, 0\.50\) m is outside the costmap.*x 0\.00\.\.2\.00"):
        planner.plan(Pose2D(-1.0, 0.5), centre(1, 1), costs, RES, ORIGIN)
    with pytest.raises(GoalOutsideMapError, match=r"goal \(0\.50, 2\.50\) m is outside"):
        planner.plan(centre(1, 1), Pose2D(0.5, 2.5), costs, RES, ORIGIN)
    with pytest.raises(StartBlockedError, match="in an obstacle"):
        planner.plan(centre(20, 20), centre(1, 1), costs, RES, ORIGIN)
    with pytest.raises(GoalBlockedError, match=r"inside an obstacle.*goal_nearest_free is off"):
        planner.plan(centre(1, 1), centre(20, 20), costs, RES, ORIGIN)
    with pytest.raises(GoalBlockedError, match="too close to an obstacle"):
        planner.plan(centre(1, 1), centre(6, 31), costs, RES, ORIGIN)
    walled = costs.copy()
    walled[10, :] = 254
    with pytest.raises(NoPathError,
                       match=r"no collision-free path from \(0\.0\d, 0\.0\d\).*cut off"):
        planner.plan(centre(1, 1), centre(30, 1), walled, RES, ORIGIN)
    unknown = costs.copy()
    unknown[35:, :] = 255
    with pytest.raises(GoalBlockedError, match="unknown space"):
        planner.plan(centre(1, 1), centre(38, 1), unknown, RES, ORIGIN)
    assert GlobalPlanner(PlannerConfig(allow_unknown=True)).plan(
        centre(1, 1), centre(38, 1), unknown, RES, ORIGIN)
    with pytest.raises(StartOutsideMapError, match=r"start \(nan, 0\.5\) is not a finite"):
        planner.plan(Pose2D(math.nan, 0.5), centre(1, 1), costs, RES, ORIGIN)
    with pytest.raises(GoalOutsideMapError, match=r"goal \(0\.5, inf\) is not a finite"):
        planner.plan(centre(1, 1), Pose2D(0.5, math.inf), costs, RES, ORIGIN)
    for err in (StartOutsideMapError, GoalBlockedError, NoPathError):
        assert issubclass(err, NavError)


def test_goal_moved_to_the_nearest_free_cell_within_the_limit() -> None:
    costs = np.zeros((60, 60), dtype=np.uint8)
    costs[20:40, 20:40] = 254  # a 1 m block
    planner = GlobalPlanner(PlannerConfig(goal_nearest_free=True, goal_nearest_free_max_m=0.4))
    res = planner.plan_detailed(centre(5, 5), centre(30, 22), costs, RES, ORIGIN)
    assert res.goal_moved
    # nearest free cell to (30, 22) is (30, 19), three cells left
    assert (res.goal.x, res.goal.y) == pytest.approx(((19 + 0.5) * RES, (30 + 0.5) * RES))
    assert res.poses[-1].distance_to(res.goal) < 1e-9
    with pytest.raises(GoalBlockedError, match=r"no free cell lies within goal_nearest_free_max_m"):
        planner.plan(centre(5, 5), centre(30, 30), costs, RES, ORIGIN)  # 10 cells deep
    off = GlobalPlanner(PlannerConfig(goal_nearest_free=False))
    with pytest.raises(GoalBlockedError):
        off.plan(centre(5, 5), centre(30, 22), costs, RES, ORIGIN)


# ---------------------------------------------------------------- frames, threads, real maps


def test_rotated_and_offset_origin() -> None:
    costs = np.zeros((40, 40), dtype=np.uint8)
    costs[0:30, 20] = 254
    origin = Pose2D(3.0, -1.0, math.pi / 2)
    grid = OccupancyGrid(costs.astype(np.int8), RES, origin)

    def world(r: int, c: int) -> Pose2D:
        x, y = grid.cell_to_world(r, c)
        return Pose2D(x, y)

    poses = GlobalPlanner(PlannerConfig()).plan(world(5, 5), world(5, 35), costs, RES, origin)
    cells = grid.world_to_cells(np.array([[p.x, p.y] for p in poses]))
    assert np.all(costs[cells[:, 0], cells[:, 1]] < 253)
    assert cells[:, 0].max() >= 30
    assert poses[-1].distance_to(world(5, 35)) < 1e-9


def test_concurrent_plans_in_threads_match_sequential_ones() -> None:
    grid = random_map(7)
    costs = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig()).costs()
    free = np.argwhere(costs < 253)
    rng = np.random.default_rng(7)
    pairs = [tuple(free[rng.integers(0, len(free), 2)]) for _ in range(6)]
    planner = GlobalPlanner(PlannerConfig())

    def one(p: tuple[np.ndarray, np.ndarray]) -> list[Pose2D] | str:
        try:
            return planner.plan(centre(*p[0]), centre(*p[1]), costs, RES, ORIGIN)
        except NavError as exc:
            return type(exc).__name__

    expected = [one(p) for p in pairs]
    results: list[object] = [None] * len(pairs)

    def worker(i: int) -> None:
        results[i] = one(pairs[i])

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(len(pairs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == expected


@pytest.mark.parametrize(("name", "yaml_name"), [("tb3_sandbox", "tb3_sandbox.yaml"),
                                                 ("willow_garage", "willow-full-0.05.yaml")])
def test_plan_on_a_real_map(shared_maps, name: str,
                            yaml_name: str) -> None:  # type: ignore[no-untyped-def]
    grid = load_map(shared_maps / name / yaml_name)
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    costs = cm.costs()
    labels, _ = ndimage.label(costs < 253, structure=np.ones((3, 3)))
    big = np.argwhere(labels == np.argmax(np.bincount(labels.ravel())[1:]) + 1)
    # the two free cells of the largest region farthest apart along its main axis
    a = big[np.argmin(big[:, 0] + big[:, 1])]
    b = big[np.argmax(big[:, 0] + big[:, 1])]
    start = Pose2D(*cm.cell_to_world(int(a[0]), int(a[1])))
    goal = Pose2D(*cm.cell_to_world(int(b[0]), int(b[1])), 0.5)
    poses = GlobalPlanner(PlannerConfig()).plan(start, goal, costs, grid.resolution_m,
                                                grid.origin)
    assert poses[0].distance_to(start) < 1e-9 and poses[-1].distance_to(goal) < 1e-9
    for p in poses:
        assert cm.cost_at(p.x, p.y) < 253
    assert path_length_m(poses) >= start.distance_to(goal) - 1e-9


# ---------------------------------------------------------------- properties


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), density=st.floats(0.0, 0.35),
       weight=st.sampled_from([1.0, 1.2, 2.0]), smooth=st.booleans())
def test_any_grid_gives_a_traversable_path_or_a_true_no_path(
        seed: int, density: float, weight: float, smooth: bool) -> None:
    rng = np.random.default_rng(seed)
    costs = rng.integers(0, 253, size=(24, 30)).astype(np.uint8)
    costs[rng.random((24, 30)) < density] = 254
    free = np.argwhere(costs < 253)
    if len(free) < 2:
        return
    s, g = free[rng.integers(0, len(free), 2)]
    planner = GlobalPlanner(PlannerConfig(heuristic_weight=weight, smooth=smooth,
                                          goal_nearest_free=False))
    lut = traversal_lut(3.0, False)
    ref = dijkstra_cost(costs, lut, (int(s[0]), int(s[1])), (int(g[0]), int(g[1])))
    try:
        res = planner.plan_detailed(centre(*s), centre(*g), costs, RES, ORIGIN)
    except NoPathError:
        assert not math.isfinite(ref)
        return
    assert math.isfinite(ref)
    assert ref - 1e-6 <= res.cost <= weight * ref * 1.001 + 1e-6
    xy = np.array([[p.x, p.y] for p in res.poses])
    fine = np.concatenate([xy[:-1] + t * (xy[1:] - xy[:-1]) for t in np.linspace(0, 1, 7)]) \
        if len(xy) > 1 else xy
    cells = np.floor(fine[:, ::-1] / RES).astype(int)
    assert np.all(costs[cells[:, 0], cells[:, 1]] < 253)
    assert res.poses[0].distance_to(centre(*s)) < 1e-9
    assert res.poses[-1].distance_to(centre(*g)) < 1e-9


def _door_costmap(gap_m: float) -> Costmap:
    """A 6 × 6 m room with a wall across x = 0 (0.3 m thick) and a door of ``gap_m`` at y = 0."""
    res = 0.05
    n = 120
    data = np.zeros((n, n), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    ys = (np.arange(n) + 0.5) * res - 3.0
    data[np.abs(ys) > gap_m / 2, 57:63] = 100
    return Costmap(OccupancyGrid(data, res, Pose2D(-3.0, -3.0, 0.0)),
                   RobotModel.from_config(RobotConfig()),
                   CostmapConfig())


def test_narrow_doors_are_crossed_straight_and_centred() -> None:
    """The narrow-passage term costs more only nearer an obstacle than the circumscribed
    radius; through a door narrower than twice that radius, approached at an angle, the plan
    crosses the wall square to it and centred, and the footprint fits at every pose."""
    from curio.nav.planner import narrow_cost

    cm = _door_costmap(0.85)
    nc = narrow_cost(cm.inscribed_radius_m, cm.circumscribed_radius_m,
                     CostmapConfig().cost_scaling_factor)
    assert 0 < nc < 253
    lut = traversal_lut(3.0, False, nc, 6.0)
    assert lut[nc - 1] == traversal_lut(3.0, False)[nc - 1]  # unchanged below it
    assert lut[252] == pytest.approx(traversal_lut(3.0, False)[252] + 6.0)
    start, goal = Pose2D(-2.0, -2.0, 0.0), Pose2D(2.0, 1.8, 0.0)
    planner = GlobalPlanner(PlannerConfig(), narrow_cost=nc)
    poses = planner.plan(start, goal, cm.costs(), cm.resolution_m, cm.origin)
    in_door = [p for p in poses if abs(p.x) <= 0.3]
    assert in_door
    assert max(abs(p.yaw) for p in in_door) < 0.35
    assert max(abs(p.y) for p in in_door) < 0.1
    arr = np.array([[p.x, p.y, p.yaw] for p in poses])
    assert (cm.footprint_costs(arr) < 254).all()
