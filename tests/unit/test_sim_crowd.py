"""The simulated crowd: deterministic for a seed, visitors in free space, the behaviour mix,
groups at exhibits, legs in the lidar, collisions split by fault, "Excuse me", followers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import Config, load_config
from curio.core.geometry import Pose2D
from curio.core.messages import ServoCommand
from curio.robot import RobotModel, footprint_radii
from curio.sim.crowd import Crowd, RoverState
from curio.sim.objects import circle_hits_polygon
from curio.sim.walkmap import WalkMap
from curio.sim.world import World
from tests.unit.test_controller import open_grid


def building(cfg: Config, visitors: int, *extra: str) -> World:
    cfg = load_config(None, [f'data_dir="{cfg.data_dir}"', f"sim.crowd.visitors={visitors}",
                             *extra])
    return World.from_config(cfg)


def run(world: World, seconds: float) -> None:
    for _ in range(int(seconds / 0.02)):
        world.step(0.02)


def test_same_seed_same_crowd(cfg: Config) -> None:
    a, b = building(cfg, 8), building(cfg, 8)
    c = building(cfg, 8, "sim.seed=7")
    for w in (a, b, c):
        run(w, 30.0)
    assert a.crowd is not None and b.crowd is not None and c.crowd is not None
    assert np.array_equal(a.crowd.pos, b.crowd.pos)
    assert a.people_truth(1.0) == b.people_truth(1.0)
    assert not np.array_equal(a.crowd.pos, c.crowd.pos)


def test_visitors_walk_in_free_space(cfg: Config) -> None:
    world = building(cfg, 20)
    crowd = world.crowd
    assert crowd is not None
    moved = np.zeros(20)
    start = crowd.pos.copy()
    for _ in range(60):
        run(world, 1.0)
        clear = crowd.walk.clearance_at(crowd.pos)
        assert (clear >= 0.5 * crowd.radius_m).all()
        moved = np.maximum(moved, np.hypot(*(crowd.pos - start).T))
    assert (moved > 1.0).sum() >= 15  # nearly everyone got somewhere
    speeds = np.hypot(crowd.vel[:, 0], crowd.vel[:, 1])
    assert speeds.max() <= 1.3 * world.cfg.sim.crowd.speed_max_mps + 1e-9


def test_the_behaviour_mix_and_groups(cfg: Config) -> None:
    world = building(cfg, 20)
    crowd = world.crowd
    assert crowd is not None
    kinds = [v.behaviour for v in crowd.visitors]
    assert {k: kinds.count(k) for k in set(kinds)} == {
        "wanderer": 7, "group": 7, "crosser": 4, "follower": 2}
    sizes = [len(g.members) for g in crowd.planner.groups.values()]
    assert sum(sizes) == 7 and all(2 <= s <= 4 for s in sizes)
    assert all(1.1 <= v.v0 <= 1.5 for v in crowd.visitors if v.behaviour == "crosser")


def test_groups_stand_together_at_an_exhibit(cfg: Config) -> None:
    world = building(cfg, 10)
    crowd = world.crowd
    assert crowd is not None
    seen_together = False
    for _ in range(120):
        run(world, 1.0)
        for group in crowd.planner.groups.values():
            idx = [crowd._index(m) for m in group.members]
            states = {crowd.visitors[i].state for i in idx}
            spread = np.ptp(crowd.pos[idx], axis=0).max()
            poi = crowd.planner.pois[group.dest]
            near = np.hypot(*(crowd.pos[idx] - poi).T).max()
            if states == {"standing"} and spread < 3.0 and near < 3.0:
                seen_together = True
    assert seen_together


def _lone_walker(cfg: Config, *extra: str) -> tuple[Crowd, WalkMap]:
    c = load_config(None, [f'data_dir="{cfg.data_dir}"', "sim.crowd.visitors=1",
                           "sim.crowd.mix_group=0", "sim.crowd.mix_follower=0",
                           "sim.crowd.mix_crosser=0", *extra])
    walk = WalkMap(open_grid(16.0), anchor=(0.0, 0.0))
    crowd = Crowd(walk, c.sim.crowd, np.random.default_rng(1), [(6.0, 0.1), (-6.0, 0.1)],
                  (0.0, 0.0), footprint_radii(np.asarray(c.robot.footprint))[1])
    crowd.pos[0] = (-5.0, 0.1)
    crowd.planner.send(crowd.visitors[0], 0, (6.0, 0.1), 0.0, (-5.0, 0.1))
    return crowd, walk


def _walk_past(crowd: Crowd, rover: RoverState, cfg: Config, seconds: float) -> list[dict]:
    footprint = [rover.pose.transform_point(x, y) for x, y in cfg.robot.footprint]
    events = []
    for _ in range(int(seconds / 0.05)):
        events += crowd.step(0.05, rover,
                             lambda x, y, r: circle_hits_polygon(x, y, r, footprint))
    return events


def _footprint(cfg: Config) -> np.ndarray:
    return RobotModel.from_config(cfg.robot).footprint


def test_an_attentive_visitor_walks_round_a_standing_rover(cfg: Config) -> None:
    crowd, _ = _lone_walker(cfg, "sim.crowd.distracted_fraction=0")
    standing = RoverState(Pose2D(0.0, 0.0, 1.0), 0.0, 0.0, _footprint(cfg))
    events = _walk_past(crowd, standing, cfg, 25.0)
    assert not events
    assert crowd.pos[0, 0] > 3.0  # got past


def test_a_visitor_who_walks_into_a_standing_rover_is_at_fault(cfg: Config) -> None:
    """A distracted visitor who never notices the rover walks into it: one collision event,
    the person's fault; they are stopped against it, not inside it."""
    crowd, _ = _lone_walker(cfg, "sim.crowd.distracted_fraction=1",
                            "sim.crowd.distracted_notice_m=0")
    crowd.visitors[0].patience_s = 0.0
    standing = RoverState(Pose2D(0.0, 0.0, 1.0), 0.0, 0.0, _footprint(cfg))
    events = _walk_past(crowd, standing, cfg, 8.0)
    assert len(events) == 1
    assert events[0]["fault"] == "person" and events[0]["with"] == ["visitor:1"]
    poly = [Pose2D(0.0, 0.0, 1.0).transform_point(x, y) for x, y in cfg.robot.footprint]
    x, y = crowd.pos[0]
    assert not circle_hits_polygon(float(x), float(y), crowd.radius_m - 0.01, poly)


@pytest.mark.parametrize(("yaw_rate_radps", "fault"), [(1.0, "rover"), (-1.0, "person")])
def test_a_turning_rover_is_at_fault_only_when_it_turns_into_the_visitor(
        cfg: Config, yaw_rate_radps: float, fault: str) -> None:
    """A distracted visitor walks along x into the rear of a rover that turns on the spot
    (facing +x). Turning anticlockwise swings its rear edge at them (the rover's doing);
    turning clockwise swings it away (theirs). Before, any turn faster than 0.17 rad/s made
    every contact the rover's, whichever way it turned."""
    crowd, _ = _lone_walker(cfg, "sim.crowd.distracted_fraction=1",
                            "sim.crowd.distracted_notice_m=0")
    crowd.visitors[0].patience_s = 0.0
    rover = RoverState(Pose2D(0.0, 0.0, 0.0), 0.0, yaw_rate_radps, _footprint(cfg))
    events = _walk_past(crowd, rover, cfg, 8.0)
    assert len(events) == 1
    assert events[0]["fault"] == fault


def test_the_rover_driving_into_a_visitor_is_at_fault(cfg: Config) -> None:
    world = building(cfg, 1, "sim.crowd.mix_group=0", "sim.crowd.mix_follower=0",
                     "sim.crowd.mix_crosser=0", "sim.crowd.distracted_fraction=1",
                     "sim.crowd.distracted_notice_m=0")
    crowd = world.crowd
    assert crowd is not None
    crowd.pos[0] = (0.9, 0.0)  # right in front of the rover at home (0, 0, 0)
    crowd.planner.send(crowd.visitors[0], 0, (0.9, 0.0), 0.0, (0.9, 0.0))
    world.apply_servo_command(ServoCommand(0.0, (400, 400, 400, -400, -400, -400),
                                           (500, 500, 500, 500)))
    run(world, 3.0)
    hits = [d for k, d in world.pop_events() if k == "collision"]
    assert hits and hits[0]["fault"] == "rover" and hits[0]["with"] == ["visitor:1"]


@pytest.mark.parametrize(("model", "circles"), [("legs", 2), ("body", 1)])
def test_the_lidar_sees_legs_or_a_body(cfg: Config, model: str, circles: int) -> None:
    world = building(cfg, 1, f'sim.crowd.lidar_model="{model}"', "sim.crowd.mix_group=0",
                     "sim.crowd.mix_follower=0", "sim.crowd.mix_crosser=0")
    crowd = world.crowd
    assert crowd is not None
    assert len(crowd.lidar_circles()) == circles
    crowd.pos[0] = (2.0, 0.0)
    scan = world.cast_scan(0.0)
    laser = world.laser_pose()
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    ang = scan.angles_rad + laser.yaw
    ok = np.isfinite(ranges)
    pts = np.column_stack([laser.x + ranges[ok] * np.cos(ang[ok]),
                           laser.y + ranges[ok] * np.sin(ang[ok])])
    on_person = np.hypot(pts[:, 0] - 2.0, pts[:, 1]) < 0.3
    assert on_person.sum() >= 3
    assert world.people_truth(0.0).people[0].visible_beams >= 3


def test_excuse_me_moves_a_visitor_out_of_the_way(cfg: Config) -> None:
    world = building(cfg, 1, "sim.crowd.mix_group=0", "sim.crowd.mix_follower=0",
                     "sim.crowd.mix_crosser=0", "sim.crowd.excuse_me_compliance=1")
    crowd = world.crowd
    assert crowd is not None
    v = crowd.visitors[0]
    crowd.pos[0] = (1.6, 0.0)
    v.state, v.dwell_until_s = "standing", math.inf
    assert crowd.hear_excuse_me(world.truth_pose) == [v.vid]
    run(world, 5.0)
    assert abs(crowd.pos[0, 1]) > 0.6  # stepped aside across the rover's line


def test_followers_follow_the_rover_during_a_tour(cfg: Config) -> None:
    world = building(cfg, 1, "sim.crowd.mix_group=0", "sim.crowd.mix_wanderer=0",
                     "sim.crowd.mix_crosser=0", "sim.crowd.mix_follower=1")
    crowd = world.crowd
    assert crowd is not None
    crowd.following = True
    run(world, 40.0)
    d = math.hypot(crowd.pos[0, 0] - world.truth_pose.x, crowd.pos[0, 1] - world.truth_pose.y)
    assert 1.0 < d < 2.2


def test_visitors_keep_off_the_rim_of_a_map_without_border_walls() -> None:
    """An open field (no walls at all): the map's edge is a wall for the walking map, so
    points of interest (and the tour stops picked from them) keep their clearance from it."""
    from curio.estimation.maps import OccupancyGrid

    field = OccupancyGrid(np.zeros((200, 200), dtype=np.int8), 0.05, Pose2D(-5.0, -5.0, 0.0))
    walk = WalkMap(field, anchor=(0.0, 0.0))
    assert walk.clearance_at(np.array([[-4.9, 0.0], [0.0, 4.9]])).max() < 0.1
    pois = walk.points_of_interest(np.random.default_rng(1), [], count=12, min_clearance_m=0.8)
    assert len(pois) == 12
    assert min(min(5.0 - abs(x), 5.0 - abs(y)) for x, y in pois) >= 0.8
