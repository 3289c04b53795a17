"""Traffic between rovers: narrow passages on plans and the right-of-way rule."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import REPO_ROOT, FleetTrafficConfig
from curio.core.geometry import Pose2D
from curio.estimation.maps import load_map
from curio.fleet.traffic import (
    SLOW_APPROACH_MIN_MPS,
    MyView,
    PassageFinder,
    PeerTable,
    PeerTrack,
    RightOfWay,
    TrafficNode,
    clear_eta_s,
    eta_s,
)

GRID = load_map(REPO_ROOT / "maps" / "curio_building.yaml")
# The workshop's 0.9 m doorway is at x 9.0..9.9, y 9.5..9.65.
INTO_WORKSHOP = np.array([[5.0, 8.3], [9.45, 8.3], [9.45, 12.0]])
OUT_OF_WORKSHOP = np.array([[9.45, 12.5], [9.45, 8.3], [13.0, 8.3]])


@pytest.fixture
def finder() -> PassageFinder:
    return PassageFinder(lambda: GRID, 1.6)


def test_the_narrow_doorway_is_a_passage_the_corridor_and_archway_are_not(finder) -> None:
    zones = finder.find(INTO_WORKSHOP, 0.0, 20.0)
    assert len(zones) == 1
    z = zones[0]
    assert z.centre == pytest.approx((9.45, 9.57), abs=0.1)
    assert z.width_m < 1.1 and z.s_in_m == pytest.approx(5.6, abs=0.2)
    through_archway = np.array([[5.0, 3.0], [5.0, 8.3], [-3.0, 8.3]])
    assert finder.find(through_archway, 0.0, 30.0) == []
    assert finder.find(INTO_WORKSHOP, 6.5, 20.0) == []  # already past it


def view(name: str, pose: Pose2D, plan: np.ndarray, start_s: float = 0.0) -> MyView:
    return MyView(name, pose, plan, start_s, True)


def peer(name: str, pose: Pose2D, plan: np.ndarray, **kw) -> PeerTrack:
    return PeerTrack(name, 0.0, pose, 0.25, True, plan, **kw)


def rule(finder: PassageFinder) -> RightOfWay:
    return RightOfWay(FleetTrafficConfig(), finder, 0.62)


def test_the_rover_that_arrives_later_gives_way_and_holds_before_the_passage(finder) -> None:
    me = view("a", Pose2D(5.0, 8.3, 0.0), INTO_WORKSHOP)
    nearer = np.array([[9.45, 11.0], [9.45, 8.3], [13.0, 8.3]])  # 1.5 m from the door
    other = peer("b", Pose2D(9.45, 11.0, -math.pi / 2), nearer)
    d = rule(finder).step(me, [other])
    assert (d.state, d.yield_to) == ("yield", "b")
    assert 1.3 <= d.hold_s_m <= 3.0
    # The other rover, seeing the same situation from its side, goes.
    d_b = rule(finder).step(view("b", other.pose, other.plan),
                            [peer("a", me.pose, INTO_WORKSHOP, state="yield", yield_to="b",
                                  zone=(9.45, 9.57))])
    assert d_b.state == "go"


def test_a_rover_in_the_passage_has_it_and_a_claim_is_kept(finder) -> None:
    me = view("a", Pose2D(5.0, 8.3, 0.0), INTO_WORKSHOP)
    inside = peer("z", Pose2D(9.45, 9.57, -math.pi / 2), OUT_OF_WORKSHOP[1:])
    assert rule(finder).step(me, [inside]).yield_to == "z"
    claimer = peer("z", Pose2D(9.45, 13.5, -math.pi / 2), OUT_OF_WORKSHOP, state="go",
                   zone=(9.45, 9.57))
    assert rule(finder).step(me, [claimer]).state == "yield"


def test_the_sooner_rover_goes_equal_ones_go_by_name_and_followers_do_not_conflict(
        finder) -> None:
    south = np.array([[9.45, 12.9], [9.45, 8.3], [13.0, 8.3]])
    a = peer("a", Pose2D(5.85, 8.3, 0.0), np.array([[5.85, 8.3], [9.45, 8.3], [9.45, 12.0]]))
    zone = finder.find(a.plan, 0.0, 20.0)[0]
    assert eta_s(a.points(), 0.0, zone) > eta_s(south, -math.pi / 2, zone) + 2.0
    assert rule(finder).step(view("b", Pose2D(9.45, 12.9, -math.pi / 2), south),
                             [a]).state == "go"
    # Mirror images 2.2 m either side of the door: the name decides, the same both ways.
    up = np.array([[9.45, 7.35], [9.45, 12.0]])
    down = np.array([[9.45, 11.85], [9.45, 7.5], [12.0, 7.5]])
    d_a = rule(finder).step(view("a", Pose2D(9.45, 7.35, math.pi / 2), up),
                            [peer("b", Pose2D(9.45, 11.85, -math.pi / 2), down)])
    d_b = rule(finder).step(view("b", Pose2D(9.45, 11.85, -math.pi / 2), down),
                            [peer("a", Pose2D(9.45, 7.35, math.pi / 2), up)])
    assert (d_a.state, d_b.state, d_b.yield_to) == ("go", "yield", "a")
    follower = peer("c", Pose2D(4.0, 8.3, 0.0), np.array([[4.0, 8.3], [9.45, 8.3],
                                                          [9.45, 12.0]]))
    me = view("a", Pose2D(5.0, 8.3, 0.0), INTO_WORKSHOP)
    assert rule(finder).step(me, [follower]).state == "clear"


def test_without_a_goal_or_rivals_there_is_nothing_to_decide(finder) -> None:
    me = MyView("a", Pose2D(5.0, 8.3, 0.0), INTO_WORKSHOP, 0.0, False)
    assert rule(finder).step(me, []).state == "clear"
    parked = PeerTrack("p", 0.0, Pose2D(9.45, 10.5, 0.0), 0.0, False)
    me = view("a", Pose2D(5.0, 8.3, 0.0), INTO_WORKSHOP)
    assert rule(finder).step(me, [parked]).state == "clear"


def test_peer_table_drops_stale_and_malformed_messages() -> None:
    table = PeerTable("me")
    table.update("me", {"t": 1.0, "x": 0, "y": 0, "yaw": 0})
    table.update("b", {"t": 10.0, "x": 1, "y": 2, "yaw": 0.5, "v": 0.2, "goal": True,
                       "plan": [[1, 2], [3, 4]]})
    table.update("c", {"t": 10.0, "x": "nope"})
    assert [p.name for p in table.fresh(11.0, 2.0)] == ["b"] and table.malformed == 1
    assert table.fresh(13.0, 2.0) == []
    track = table.tracks(11.0, 2.0)[0]
    assert track.id == "rover:b" and track.path == ((1.0, 2.0), (3.0, 4.0))
    assert track.vx_mps == pytest.approx(0.2 * math.cos(0.5))


def test_a_rover_giving_way_slows_to_reach_its_staging_point_as_the_other_clears(
        finder) -> None:
    """On its way to the staging point the rover that gives way is slowed so that it gets there
    ``slow_approach_lead_s`` before the other is expected through (never below the floor); no
    limit at the staging point, with the right of way, or without the other's messages."""
    node = TrafficNode(FleetTrafficConfig(), "a", Bus(), SimClock(), finder, 0.62, 0.45,
                       lambda: True)
    me = view("a", Pose2D(7.0, 8.3, 0.0), INTO_WORKSHOP, start_s=2.0)
    far = peer("b", Pose2D(9.45, 13.5, -math.pi / 2),  # it has claimed the doorway
               np.array([[9.45, 13.5], [9.45, 8.3], [13.0, 8.3]]), state="go",
               zone=(9.45, 9.57))
    node.peers.peers["b"] = far
    node.decision = node.rule.step(me, [far])
    d = node.decision
    assert (d.state, d.yield_to) == ("yield", "b") and d.zone is not None
    to_staging = d.zone.s_in_m - d.hold_s_m
    spare = clear_eta_s(far, d.zone, 0.9) - 4.0
    assert spare > 0 and to_staging > 0
    limit = node.speed_limit(me.pose)
    assert limit == pytest.approx(max(SLOW_APPROACH_MIN_MPS, to_staging / spare))
    assert limit < 0.2  # well under the controller's 0.3 m/s
    node.peers.peers["b"] = peer("b", Pose2D(9.45, 30.0, -math.pi / 2),
                                 np.array([[9.45, 30.0], [9.45, 8.3], [13.0, 8.3]]),
                                 state="go", zone=(9.45, 9.57))
    assert node.speed_limit(me.pose) == SLOW_APPROACH_MIN_MPS  # very far: the floor
    node.peers.peers.clear()
    assert node.speed_limit(me.pose) == math.inf                # not heard: drive on
    node.peers.peers["b"] = far
    node.decision = replace(d, hold_s_m=d.zone.s_in_m)          # at the staging point
    assert node.speed_limit(me.pose) == math.inf                # (the hold stops it)
    node.decision = replace(d, state="go", yield_to=None)
    assert node.speed_limit(me.pose) == math.inf
    node.decision = d
    node.cfg = FleetTrafficConfig(slow_approach_lead_s=0.0)
    assert node.speed_limit(me.pose) == math.inf                # switched off
