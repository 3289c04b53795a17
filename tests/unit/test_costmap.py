"""Costmap: inflation values, marking and ray-trace clearing, rolling window, footprint cost."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import CostmapConfig, RobotConfig
from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage, LaserScan, PoseWithCovariance
from curio.core.topics import COSTMAP, LOCAL_COSTMAP, MAP, POSE, SCAN
from curio.estimation.maps import OccupancyGrid, load_map
from curio.nav.costmap import Costmap, CostmapNode, costs_to_percent
from curio.nav.costs import INSCRIBED, LETHAL, NO_INFORMATION
from curio.robot import RobotModel, footprint_radii, pad_footprint

RES = 0.05


def free_grid(n: int = 200, origin: Pose2D | None = None) -> OccupancyGrid:
    """An all-free n × n map at 5 cm (10 m square for n = 200), origin at (0, 0)."""
    return OccupancyGrid(np.zeros((n, n), dtype=np.int8), RES, origin or Pose2D())


def empty_costs() -> np.ndarray:
    """The costs of :func:`free_grid` with no obstacle: only its rim (the map's edge)."""
    return Costmap(free_grid(), RobotModel.from_config(RobotConfig()), CostmapConfig()).costs()


def make_scan(ranges: np.ndarray, stamp: float = 0.0) -> LaserScan:
    n = len(ranges)
    return LaserScan(stamp=stamp, angle_min_rad=-math.pi, angle_increment_rad=2 * math.pi / n,
                     range_min_m=0.15, range_max_m=12.0, ranges_m=ranges.astype(np.float64))


def beam_index(angle_rad: float, n: int = 360) -> int:
    return round((angle_rad + math.pi) / (2 * math.pi / n)) % n


def hit_at(cm: Costmap, pose: Pose2D, laser_angle: float, range_m: float) -> tuple[int, int]:
    """The cell a laser return at (angle, range) in the laser frame lands in."""
    laser = pose @ cm.laser_in_base
    x = laser.x + range_m * math.cos(laser.yaw + laser_angle)
    y = laser.y + range_m * math.sin(laser.yaw + laser_angle)
    return cm.world_to_cell(x, y)


# ---------------------------------------------------------------- footprint geometry


def test_footprint_padding_and_radii() -> None:
    poly = pad_footprint(RobotConfig().footprint, 0.01)
    assert np.allclose(np.abs(poly), [[0.34, 0.32]] * 4)
    inscribed, circumscribed = footprint_radii(poly)
    assert inscribed == pytest.approx(0.32)
    assert circumscribed == pytest.approx(math.hypot(0.34, 0.32))


def test_footprint_radii_of_an_off_centre_triangle() -> None:
    tri = np.array([[1.0, 0.0], [-1.0, 1.0], [-1.0, -1.0]])
    inscribed, circumscribed = footprint_radii(tri)
    # edge from (1,0) to (-1,1): distance of the origin is |x + 2y - 1| / sqrt(5)
    assert inscribed == pytest.approx(1.0 / math.sqrt(5.0))
    assert circumscribed == pytest.approx(math.sqrt(2.0))


# ---------------------------------------------------------------- inflation


def expected_cost(d_m: float, inscribed: float = 0.32, radius: float = 0.55,
                  k: float = 10.0) -> int:
    """Hand formula: 254 at the obstacle, 253 inside the inscribed radius, decay to the radius."""
    if d_m == 0.0:
        return 254
    if d_m <= inscribed:
        return 253
    if d_m <= radius:
        return min(252, math.floor(253.0 * math.exp(-k * (d_m - inscribed))))
    return 0


def test_inflation_matches_hand_computed_distances() -> None:
    grid = free_grid(100)
    grid.data[50, 50] = 100
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    assert cm.inscribed_radius_m == pytest.approx(0.32)
    costs = cm.costs()
    for dr, dc in [(0, 0), (0, 1), (0, 6), (3, 4), (0, 7), (5, 5), (0, 8), (6, 6), (0, 11),
                   (0, 12), (8, 8), (20, 0)]:
        d = math.hypot(dr, dc) * RES
        assert costs[50 + dr, 50 + dc] == expected_cost(d), (dr, dc, d)
    # spot values worked out by hand: 7 cells = 0.35 m -> floor(253 e^-0.3) = 187
    assert costs[50, 57] == 187
    # 11 cells = 0.55 m (the radius itself) -> floor(253 e^-2.3) = 25; 12 cells -> 0
    assert costs[50, 61] == 25
    assert costs[50, 62] == 0


def test_inflation_honours_radius_and_scaling_settings() -> None:
    grid = free_grid(100)
    grid.data[50, 50] = 100
    cfg = CostmapConfig(inflation_radius_m=1.0, cost_scaling_factor=2.0, footprint_padding_m=0.0)
    costs = Costmap(grid, RobotModel.from_config(RobotConfig()), cfg).costs()
    for dc in (5, 6, 7, 10, 19, 20, 21):
        d = dc * RES
        assert costs[50, 50 + dc] == expected_cost(d, 0.31, 1.0, 2.0), dc


def test_unknown_static_cells_stay_unknown_unless_inflated_to_inscribed() -> None:
    grid = free_grid(60)
    grid.data[:, 40:] = -1
    grid.data[30, 38] = 100
    costs = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig()).costs()
    assert costs[10, 50] == NO_INFORMATION
    assert costs[30, 40] == INSCRIBED  # unknown but within the inscribed radius of a wall
    assert costs[20, 20] == 0


def test_the_edge_of_the_map_is_a_wall() -> None:
    """A map without border walls (an open field): the rover's footprint cannot leave the
    grid, so its rim is lethal and inflated like a wall and no goal lies there."""
    cm = Costmap(free_grid(100), RobotModel.from_config(RobotConfig()), CostmapConfig())
    costs = cm.costs()
    assert (costs[0, :] == LETHAL).all() and (costs[:, -1] == LETHAL).all()
    assert costs[2, 50] >= INSCRIBED  # 0.1 m from the rim: the footprint would leave the map
    assert costs[50, 50] == 0 and costs[20, 50] == 0
    edge_m = 0.05 * np.arange(1, 12)
    assert list(costs[1:12, 50]) == [expected_cost(d) for d in edge_m]


def test_costs_snapshot_is_read_only_and_replaced_on_change() -> None:
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), CostmapConfig())
    before = cm.costs()
    with pytest.raises(ValueError):
        before[0, 0] = 1
    pose = Pose2D(5.0, 5.0, 0.0)
    ranges = np.full(360, np.inf)
    ranges[beam_index(0.0)] = 2.0
    cm.update_from_scan(make_scan(ranges), pose)
    after = cm.costs()
    assert after is not before
    assert np.array_equal(before, empty_costs())  # the old snapshot is untouched


# ---------------------------------------------------------------- marking and clearing


def test_obstacle_marked_within_one_scan_then_cleared_when_seen_free() -> None:
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), CostmapConfig())
    pose = Pose2D(5.0, 5.0, 0.3)
    ranges = np.full(360, np.inf)
    i = beam_index(0.0)
    ranges[i] = 2.0
    v0 = cm.version
    cm.update_from_scan(make_scan(ranges), pose)
    r, c = hit_at(cm, pose, -math.pi + i * 2 * math.pi / 360, 2.0)
    assert cm.costs()[r, c] == LETHAL
    assert cm.version > v0
    assert cm.costs()[r, c - 8] == INSCRIBED or cm.costs()[r, c - 8] > 0  # inflated around it
    x, y = cm.cell_to_world(r, c)
    assert cm.is_lethal(x, y)
    # the same beam now sees nothing: the ray clears the mark
    cm.update_from_scan(make_scan(np.full(360, np.inf), stamp=0.1), pose)
    assert cm.costs()[r, c] == 0
    assert not cm.obstacle_mask().any()
    assert np.array_equal(cm.costs(), empty_costs())


def test_longer_return_clears_the_old_mark_and_marks_the_new_end() -> None:
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), CostmapConfig())
    pose = Pose2D(5.0, 5.0, 0.0)
    i = beam_index(0.0)
    ranges = np.full(360, np.inf)
    ranges[i] = 1.5
    cm.update_from_scan(make_scan(ranges), pose)
    near = hit_at(cm, pose, -math.pi + i * 2 * math.pi / 360, 1.5)
    ranges[i] = 3.0
    cm.update_from_scan(make_scan(ranges), pose)
    far = hit_at(cm, pose, -math.pi + i * 2 * math.pi / 360, 3.0)
    assert cm.costs()[near] != LETHAL
    assert cm.costs()[far] == LETHAL


def test_returns_beyond_obstacle_range_are_not_marked_but_clear() -> None:
    cfg = CostmapConfig(obstacle_range_m=2.0, raytrace_range_m=3.0)
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), cfg)
    pose = Pose2D(2.0, 5.0, 0.0)
    ranges = np.full(360, np.nan)
    ranges[beam_index(0.0)] = 2.5
    cm.update_from_scan(make_scan(ranges), pose)
    assert not cm.obstacle_mask().any()


def test_raytrace_range_limits_clearing() -> None:
    cfg = CostmapConfig(obstacle_range_m=5.5, raytrace_range_m=2.0)
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), cfg)
    pose = Pose2D(2.0, 5.0, 0.0)
    i = beam_index(0.0)
    ranges = np.full(360, np.nan)
    ranges[i] = 4.0
    cm.update_from_scan(make_scan(ranges), pose)
    mark = hit_at(cm, pose, -math.pi + i * 2 * math.pi / 360, 4.0)
    assert cm.costs()[mark] == LETHAL
    ranges[i] = np.inf  # sees nothing, but clearing reaches only 2 m: the mark at 4 m stays
    cm.update_from_scan(make_scan(ranges, 0.1), pose)
    assert cm.costs()[mark] == LETHAL


def test_rays_never_clear_the_static_map() -> None:
    grid = free_grid()
    grid.data[100, 130] = 100  # 1.5 m ahead of (5.0, 5.0) along +x, roughly
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    cm.update_from_scan(make_scan(np.full(360, np.inf)), Pose2D(5.0, 5.0, 0.0))
    assert cm.costs()[100, 130] == LETHAL


def test_laser_mounting_offset_is_applied() -> None:
    robot = RobotModel.from_config(RobotConfig(laser_pose=(0.5, 0.2, math.pi / 2)))
    cm = Costmap(free_grid(), robot, CostmapConfig())
    pose = Pose2D(5.0, 5.0, math.pi / 2)
    ranges = np.full(360, np.nan)
    ranges[beam_index(0.0)] = 1.0  # the laser's +x, which points along map -x here
    cm.update_from_scan(make_scan(ranges), pose)
    # laser in map: (5 - 0.2, 5 + 0.5) facing -x -> return at (3.8, 5.5)
    r, c = cm.world_to_cell(3.8, 5.5)
    marked = np.argwhere(cm.obstacle_mask())
    assert marked.shape[0] == 1
    assert abs(marked[0, 0] - r) <= 1 and abs(marked[0, 1] - c) <= 1


def test_unknown_cells_become_free_when_a_ray_crosses_them() -> None:
    grid = OccupancyGrid(np.full((200, 200), -1, dtype=np.int8), RES)
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    assert cm.costs()[100, 120] == NO_INFORMATION
    ranges = np.full(360, np.nan)
    ranges[beam_index(0.0)] = np.inf
    cm.update_from_scan(make_scan(ranges), Pose2D(5.0, 5.0, 0.0))
    laser_r, _ = cm.world_to_cell(5.0, 5.0 + 0.078)
    assert cm.costs()[laser_r, 120] == 0
    assert cm.costs()[laser_r + 20, 120] == NO_INFORMATION


def test_clear_around_removes_marks_only_within_radius() -> None:
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), CostmapConfig())
    pose = Pose2D(5.0, 5.0, 0.0)
    ranges = np.full(360, np.nan)
    ranges[beam_index(0.0)] = 0.8
    ranges[beam_index(math.pi / 2)] = 3.0
    cm.update_from_scan(make_scan(ranges), pose)
    assert cm.obstacle_mask().sum() == 2
    cm.clear_around(pose, 1.5)
    assert cm.obstacle_mask().sum() == 1
    cm.reset_obstacles()
    assert not cm.obstacle_mask().any()
    assert np.array_equal(cm.costs(), empty_costs())


def test_scan_update_is_vectorised_and_only_touches_its_window() -> None:
    grid = free_grid(1000)  # 50 m
    grid.data[900, 900] = 100
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    far_before = cm.costs()[890:910, 890:910].copy()
    ranges = np.full(720, 1.0)
    scan = LaserScan(0.0, -math.pi, 2 * math.pi / 720, 0.15, 12.0, ranges)
    cm.update_from_scan(scan, Pose2D(5.0, 5.0, 0.0))
    assert np.array_equal(cm.costs()[890:910, 890:910], far_before)
    assert cm.obstacle_mask().sum() > 50  # a ring of returns 1 m around the laser


def test_a_return_next_to_a_mapped_wall_is_the_wall_not_a_new_obstacle() -> None:
    """Lidar noise puts wall returns in the free cell in front of the wall: with the default
    tolerance (1 cell) they mark nothing; two cells out they do; tolerance 0 marks all."""
    pose = Pose2D(5.0, 5.0, 0.0)
    for tolerance, offsets_marked in ((1, {1: False, 2: True}), (0, {1: True, 2: True})):
        for offset, marked in offsets_marked.items():
            grid = free_grid()
            probe = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
            r, c = hit_at(probe, pose, 0.0, 1.5)
            grid.data[r, c + offset] = 100  # the mapped wall, ``offset`` cells beyond the hit
            cm = Costmap(grid, RobotModel.from_config(RobotConfig()),
                         CostmapConfig(static_mark_tolerance_cells=tolerance))
            ranges = np.full(360, np.nan)
            ranges[beam_index(0.0)] = 1.5
            cm.update_from_scan(make_scan(ranges), pose)
            assert bool(cm.obstacle_mask()[r, c]) is marked, (tolerance, offset)
            assert bool(cm.costs()[r, c] == LETHAL) is marked, (tolerance, offset)


def test_returns_on_mapped_walls_do_not_reinflate_but_a_new_obstacle_does() -> None:
    """Marks on cells the static map already holds change no cost: the costs snapshot (and
    its version) stays; a return in free space re-inflates at once."""
    grid = free_grid()
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    pose = Pose2D(5.0, 5.0, 0.0)
    r, c = hit_at(cm, pose, 0.0, 1.5)
    grid.data[r, c] = 100
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    ranges = np.full(360, np.nan)
    ranges[beam_index(0.0)] = 1.5
    before, version = cm.costs(), cm.version
    cm.update_from_scan(make_scan(ranges), pose)
    assert cm.obstacle_mask()[r, c]  # the layer holds the return...
    assert cm.costs() is before and cm.version == version  # ...but nothing was recomputed
    ranges[beam_index(math.pi / 2)] = 1.0
    cm.update_from_scan(make_scan(ranges, 0.1), pose)
    r2, c2 = hit_at(cm, pose, math.pi / 2, 1.0)
    assert cm.version == version + 1
    assert cm.costs()[r2, c2] == LETHAL


# ---------------------------------------------------------------- rolling window, footprint


def test_rolling_window_follows_the_rover() -> None:
    grid = free_grid(400)  # 20 m
    grid.data[200, 260] = 100  # (13.0, 10.0)
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    costs, origin = cm.local_window(Pose2D(11.0, 10.0, 0.7))
    assert costs.shape == (120, 120)
    assert origin.x == pytest.approx(11.0 - 3.0) and origin.y == pytest.approx(10.0 - 3.0)
    assert costs[int((10.0 - origin.y) / RES), int((13.0 - origin.x) / RES)] == LETHAL
    # near the map's edge the window reaches outside: those cells are unknown
    edge, edge_origin = cm.local_window(Pose2D(1.0, 1.0, 0.0))
    assert edge[0, 0] == NO_INFORMATION
    assert edge[round((1.0 - edge_origin.y) / RES), round((1.0 - edge_origin.x) / RES)] \
        == 0
    msg = cm.local_message(1.0, Pose2D(11.0, 10.0, 0.0))
    assert msg.data.shape == (120, 120) and msg.kind == "local_costmap"


def test_footprint_cost_sees_the_rectangle() -> None:
    grid = free_grid(100)
    grid.data[50, 58] = 100  # cell x 2.90..2.95 m: its near edge 0.375 m ahead of (2.525, 2.525)
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    x, y = cm.cell_to_world(50, 50)
    # facing the obstacle: the footprint's front edge (0.34 m) stops just short of it
    assert cm.footprint_cost(Pose2D(x, y, 0.0)) == INSCRIBED
    # 5 cm closer: the front edge (x + 0.34) enters the obstacle cell
    assert cm.footprint_cost(Pose2D(x + 0.05, y, 0.0)) == LETHAL
    # turned sideways the half-width along x is 0.32 m: still clear
    assert cm.footprint_cost(Pose2D(x, y, math.pi / 2)) < LETHAL
    # far away: free
    assert cm.footprint_cost(Pose2D(1.0, 1.0, 0.0)) == 0
    # partly off the map counts as lethal
    assert cm.footprint_cost(Pose2D(0.1, 1.0, 0.0)) == LETHAL
    batch = cm.footprint_costs(np.array([[x, y, 0.0], [x + 0.05, y, 0.0], [1.0, 1.0, 0.0]]))
    assert batch.tolist() == [INSCRIBED, LETHAL, 0]


def test_is_lethal_and_cost_at() -> None:
    grid = free_grid(100)
    grid.data[50, 50] = 100
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    x, y = cm.cell_to_world(50, 50)
    assert cm.is_lethal(x, y)
    assert cm.is_lethal(x + 0.2, y)  # inscribed
    assert not cm.is_lethal(x + 0.5, y)
    assert cm.is_lethal(-1.0, 0.0)  # off the map
    assert cm.cost_at(x, y) == LETHAL


def test_display_scaling() -> None:
    scaled = costs_to_percent(np.array([0, 1, 128, 252, 253, 254, 255], dtype=np.uint8))
    assert scaled.tolist()[0] == 0 and scaled.tolist()[-3:] == [99, 100, -1]
    assert 0 < scaled[1] <= scaled[2] <= scaled[3] < 99


def test_rotated_map_origin() -> None:
    grid = free_grid(100, origin=Pose2D(1.0, 2.0, math.pi / 2))
    grid.data[10, 20] = 100
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    x, y = cm.cell_to_world(10, 20)
    # column runs along map +y, row along map -x
    assert (x, y) == pytest.approx((1.0 - 10.5 * RES, 2.0 + 20.5 * RES))
    assert cm.cost_at(x, y) == LETHAL


def test_real_map_loads_into_a_costmap(shared_maps) -> None:  # type: ignore[no-untyped-def]
    grid = load_map(shared_maps / "willow_garage" / "willow-full-0.05.yaml")
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    costs = cm.costs()
    assert costs.shape == grid.data.shape
    assert np.all(costs[grid.occupied_mask()] == LETHAL)
    assert (costs == 0).sum() > 100_000
    assert cm.grid_info.shape == costs.shape and cm.grid_info.resolution_m == 0.05


# ---------------------------------------------------------------- the node on the bus


async def test_costmap_node_publishes_global_and_local_costmaps(bus: Bus) -> None:
    clock = SimClock()
    cfg = CostmapConfig(update_rate_hz=5.0, global_publish_rate_hz=100.0)
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), cfg)
    node = CostmapNode(cm, bus, clock, cfg)
    global_sub = bus.subscribe(COSTMAP, maxsize=10)
    local_sub = bus.subscribe(LOCAL_COSTMAP, maxsize=10)
    bus.publish(POSE, PoseWithCovariance(0.0, Pose2D(5.0, 5.0, 0.0)))
    task = asyncio.create_task(node.run())
    await clock.advance(0.5)
    first = global_sub.drain()
    assert len(first) == 1  # nothing changed after the first publication
    assert local_sub.drain()
    version = first[-1].version
    ranges = np.full(360, np.inf)
    ranges[beam_index(0.0)] = 1.0
    bus.publish(SCAN, make_scan(ranges, stamp=0.5))
    await clock.advance(0.5)
    msgs = global_sub.drain()
    assert len(msgs) == 1 and msgs[-1].version > version
    assert int(msgs[-1].data.max()) == 100  # the new obstacle, scaled for display
    assert node.updates == 1
    # a new map replaces the static layer
    wall = np.zeros((200, 200), dtype=np.int8)
    wall[:, 150] = 100
    bus.publish(MAP, GridMessage(1.0, wall, RES, Pose2D(), version=2, kind="map"))
    await clock.advance(0.5)
    assert cm.costs()[10, 150] == LETHAL
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


def test_updated_map_on_the_same_grid_is_applied_incrementally_keeping_marks() -> None:
    grid = free_grid(400)
    cm = Costmap(grid, RobotModel.from_config(RobotConfig()), CostmapConfig())
    pose = Pose2D(5.0, 5.0, 0.0)
    ranges = np.full(360, np.nan)
    ranges[beam_index(0.0)] = 2.0
    cm.update_from_scan(make_scan(ranges), pose)
    marks = cm.obstacle_mask()
    grown = grid.copy()
    grown.data[300, 300] = 100
    grown.data[350:, :] = -1
    cm.set_static_map(grown)
    full = Costmap(grown, RobotModel.from_config(RobotConfig()), CostmapConfig())
    full.update_from_scan(make_scan(ranges), pose)
    assert np.array_equal(cm.obstacle_mask(), marks)  # the obstacle layer survives
    assert np.array_equal(cm.costs(), full.costs())  # same result as building from scratch
    # a map on another grid starts over
    other = OccupancyGrid(np.zeros((100, 120), dtype=np.int8), RES, Pose2D(-1.0, 0.0, 0.0))
    cm.set_static_map(other)
    assert cm.costs().shape == (100, 120) and not cm.obstacle_mask().any()
    assert cm.origin == Pose2D(-1.0, 0.0, 0.0)


async def test_costmap_node_places_a_scan_with_the_pose_at_its_stamp(bus: Bus) -> None:
    clock = SimClock()
    cfg = CostmapConfig()
    cm = Costmap(free_grid(), RobotModel.from_config(RobotConfig()), cfg)
    node = CostmapNode(cm, bus, clock, cfg)
    for k in range(11):  # driving along +x at 1 m/s, poses every 0.1 s
        bus.publish(POSE, PoseWithCovariance(k * 0.1, Pose2D(2.0 + k * 0.1, 5.0, 0.0)))
    def at(t: float) -> tuple[float, float, float]:
        pose = node.pose_at(t)
        assert pose is not None
        return pose.as_tuple()

    assert at(0.45) == pytest.approx((2.45, 5.0, 0.0))
    assert at(5.0) == pytest.approx((3.0, 5.0, 0.0))  # newer than the history: the newest
    assert at(-1.0) == pytest.approx((2.0, 5.0, 0.0))
    ranges = np.full(360, np.nan)
    ranges[beam_index(math.pi / 2)] = 1.0  # to the left of the laser
    bus.publish(SCAN, make_scan(ranges, stamp=0.3))
    node.step(1.0)
    marked = np.argwhere(cm.obstacle_mask())
    # placed from the pose at 0.3 s (x = 2.3) plus the laser's offset, not from the newest (3.0)
    assert marked.shape[0] == 1
    x, _ = cm.cell_to_world(int(marked[0, 0]), int(marked[0, 1]))
    assert x == pytest.approx(2.3 + 0.152, abs=0.05)


def test_scan_on_a_rotated_map_marks_the_right_place() -> None:
    grid = free_grid(200, origin=Pose2D(10.0, -2.0, math.pi / 2))  # covers x 0..10, y -2..8
    cm = Costmap(grid, RobotModel.from_config(RobotConfig(laser_pose=(0.0, 0.0, 0.0))),
                 CostmapConfig())
    pose = Pose2D(5.0, 3.0, math.pi / 4)
    ranges = np.full(360, np.inf)
    ranges[beam_index(0.0)] = 2.0
    cm.update_from_scan(make_scan(ranges), pose)
    hit_x = 5.0 + 2.0 * math.cos(math.pi / 4)
    hit_y = 3.0 + 2.0 * math.sin(math.pi / 4)
    assert cm.cost_at(hit_x, hit_y) == LETHAL
    assert cm.obstacle_mask().sum() == 1
    # inflation around the hit, in map coordinates: 0.2 m away inscribed, 1 m away free
    back = 2.0 - 0.2
    assert cm.cost_at(5.0 + back * math.cos(math.pi / 4), 3.0 + back * math.sin(math.pi / 4)) \
        == INSCRIBED
    assert cm.cost_at(5.0 + math.cos(math.pi / 4), 3.0 + math.sin(math.pi / 4)) == 0
