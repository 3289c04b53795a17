"""'Thanks!' only from fresh evidence: the clearance probe judges the held route from the scans.

Reproduces the field report of issue 11: during a help episode the recovery's costmap clearing
made the way look clear while the door was still closed. The old probe (a plan on the live
costmap) says "clear" after the clearing; the clearance probe, which reads the scans along the
route, does not — and says clear on the first scan after the door opens.
"""

from __future__ import annotations

import numpy as np

from curio.bt.probe import WayProbe
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import PoseWithCovariance
from curio.core.topics import HELP_BLOCKAGE, POSE, SCAN, make_bus
from curio.estimation.maps import OccupancyGrid
from curio.nav.clearance import ClearanceProbe, StaticView, judge_route
from curio.nav.costmap import Costmap
from curio.nav.costs import LETHAL
from curio.nav.planner import GlobalPlanner
from curio.robot import RobotModel
from curio.sim.objects import Door
from curio.sim.world import World, WorldSpec

RES = 0.05


def _room() -> OccupancyGrid:
    """8 × 4 m, a wall across at x = 3.0–3.15 with a 1.1 m doorway (y 1.45–2.55)."""
    data = np.zeros((80, 160), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    data[:, 60:63] = 100
    data[29:51, 60:63] = 0
    return OccupancyGrid(data, RES, Pose2D(), name="room")


def _setup() -> tuple[Config, World, Costmap, GlobalPlanner, RobotModel]:
    cfg = Config()
    robot = RobotModel.from_config(cfg.robot)
    door = Door("door", (3.075, 1.45), (3.075, 2.55), is_open=False)
    world = World(_room(), cfg, Pose2D(1.2, 2.0, 0.0), WorldSpec(doors=[door]), robot)
    costmap = Costmap(_room(), robot, cfg.nav.costmap)
    return cfg, world, costmap, GlobalPlanner(cfg.nav.planner), robot


def _scan(bus: object, world: World, t: float, costmap: Costmap | None = None) -> None:
    scan = world.cast_scan(t)
    bus.publish(SCAN, scan)  # type: ignore[attr-defined]
    bus.publish(POSE, PoseWithCovariance(t, world.truth_pose))  # type: ignore[attr-defined]
    if costmap is not None:
        costmap.update_from_scan(scan, world.truth_pose)


async def test_a_cleared_costmap_is_not_evidence_but_an_open_door_is() -> None:
    _, world, costmap, planner, robot = _setup()
    bus, clock = make_bus(), SimClock()
    goal = Pose2D(6.0, 2.0, 0.0)
    for k in range(5):
        _scan(bus, world, 0.1 * k, costmap)
    old = WayProbe(planner, costmap, bus, clock)
    new = ClearanceProbe(planner, costmap, bus, clock, robot.laser_in_base,
                         costmap.inscribed_radius_m)
    old.start(goal, 0.5)
    assert old.poll() is not None and not old.poll().clear  # type: ignore[union-attr]
    assert new.start(goal, 0.5)
    _scan(bus, world, 0.6, costmap)
    answer = new.poll()
    assert answer is not None and not answer.clear and "blocked" in answer.reason
    assert new.blocked_at_m is not None and 1.0 < new.blocked_at_m < 2.5  # the door
    blockage = bus.latest(HELP_BLOCKAGE)
    assert blockage is not None and blockage.circles
    assert all(abs(x - 3.05) < 0.15 for x, _, _ in blockage.circles)
    # The recovery clears the costmap around the rover while the door is still closed.
    costmap.clear_around(world.truth_pose, 3.0)
    old.start(goal, 0.7)
    assert old.poll().clear  # type: ignore[union-attr]  # the old probe is fooled
    _scan(bus, world, 0.8)
    answer = new.poll()
    assert answer is not None and not answer.clear  # the scans still see the door
    world.set_door("door", True)
    _scan(bus, world, 0.9)
    answer = new.poll()
    assert answer is not None and answer.clear and answer.started_s == 0.9


def test_judge_route_sees_a_box_beside_the_line_of_sight_and_not_past_a_corner() -> None:
    _, world, _, _, robot = _setup()
    world.set_door("door", True)
    static = StaticView(_room().occupied_mask(), RES, Pose2D())
    route = np.array([[1.2 + 0.05 * k, 2.0] for k in range(100)])
    laser = world.truth_pose @ robot.laser_in_base
    clear = judge_route(route, world.truth_pose, laser, world.cast_scan(0.0), static, 0.32)
    assert clear.blocked_at_m is None and clear.seen_free_m > 3.5
    box = world.add_box(2.2, 2.25, 0.2, 0.2)  # in the corridor, beside the beam along the route
    boxed = judge_route(route, world.truth_pose, laser, world.cast_scan(0.1), static, 0.32)
    assert boxed.blocked_at_m is not None and abs(boxed.blocked_at_m - 1.0) < 0.2
    world.remove_object(box)
    # Through the doorway, then south behind the wall: judged only as far as the laser sees.
    bend = np.array([[1.2 + 0.05 * k, 2.0] for k in range(49)]
                    + [[3.6, 2.0 - 0.05 * k] for k in range(1, 31)])
    seen = judge_route(bend, world.truth_pose, laser, world.cast_scan(0.2), static, 0.32)
    assert seen.blocked_at_m is None
    assert 2.5 < seen.judged_m < 3.2  # the samples below y = 1.4 are behind the wall


def test_the_static_costs_are_made_once_until_the_map_or_the_zones_change(
        monkeypatch: object) -> None:
    """A help episode with no route asks for the static costs every quarter second; each
    time two whole-map distance transforms ran (tens of MB of temporaries: the resident
    size of the soak's rover swung by 7–11 MB through help episodes)."""
    from curio.nav import clearance

    _, _, costmap, planner, robot = _setup()
    probe = ClearanceProbe(planner, costmap, make_bus(), SimClock(), robot.laser_in_base,
                           costmap.inscribed_radius_m)
    calls = []
    edt = clearance.ndimage.distance_transform_edt
    monkeypatch.setattr(clearance.ndimage, "distance_transform_edt",  # type: ignore[attr-defined]
                        lambda a, *k, **kw: calls.append(1) or edt(a, *k, **kw))
    first = probe.static_costs()
    assert len(calls) == 2 and not first.flags.writeable
    assert probe.static_costs() is first and len(calls) == 2  # nothing changed: no transform
    zone = costmap.keepout_mask()
    zone[10:20, 100:110] = True
    costmap.set_keepout(zone)
    again = probe.static_costs()
    assert len(calls) == 4 and again is not first
    assert (again[10:20, 100:110] == LETHAL).all()
    assert probe.static_costs() is again and len(calls) == 4
