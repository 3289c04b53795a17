"""Other rovers as moving obstacles with known intent: predicted along their plans, and the
people-aware controller reacting to where a rover *will* be, not where a straight line says."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import Config, load_config
from curio.core.geometry import Pose2D
from curio.core.messages import PeopleTracks, PersonTrack
from curio.fleet.intent import RoverIntent, predict_along
from curio.fleet.traffic import PeerTable
from curio.fleet.transport import MemoryNetwork, MemoryTransport
from curio.nav.controller import ControlOutput, ControlStatus, LocalController
from curio.nav.costmap import Costmap
from curio.people.stage import PeopleStage
from curio.robot import RobotModel
from tests.unit.test_controller import open_grid, straight_plan

TIMES = np.arange(0.0, 4.01, 0.5)
# A rover beside our lane, driving +x now, whose plan turns left across our lane.
TURNING = {"t": 100.0, "x": 1.0, "y": -1.6, "yaw": 0.0, "v": 0.5, "goal": True,
           "plan": [[1.2, -1.6], [1.2, -0.8], [1.2, 0.0], [1.2, 0.8], [1.2, 2.0]],
           "state": "go", "r": 0.45}


def test_a_prediction_follows_the_path_and_stops_where_it_ends_or_holds() -> None:
    path = np.array([[1.0, 0.0], [1.0, 2.0]])
    at = predict_along((0.0, 0.0), path, 0.5, np.array([0.0, 1.0, 2.0, 4.0, 10.0]))
    assert np.allclose(at, np.array([[0, 0], [0.5, 0], [1, 0], [1, 1], [1, 2]], dtype=float))
    held = predict_along((0.0, 0.0), path, 0.5, np.array([10.0]), stop_after_m=1.5)
    assert np.allclose(held, [[1.0, 0.5]])


def test_holding_stale_and_yielding_rovers() -> None:
    table = PeerTable("me")
    wall = {"t": 100.2}
    intent = RoverIntent(table, lambda: wall["t"], 2.0)
    table.update("a", TURNING)
    table.update("b", {**TURNING, "t": 100.2, "y": 3.0, "state": "yield", "v": 0.0,
                       "yield": "a"})
    table.update("c", {**TURNING, "t": 95.0, "y": 6.0})               # not heard for 5 s
    table.update("d", {**TURNING, "t": 100.2, "y": -4.0, "state": "yield", "yield": "a",
                       "plan": [[3.0, -4.0]], "stop_in": 0.5})
    table.update("e", {**TURNING, "t": 100.2, "y": -6.0, "state": "yield", "yield": "me"})
    known = intent(TIMES)  # e gives way to us: the right of way settled it, left out
    assert known.names == ("rover:a", "rover:b", "rover:d")
    a, b, d = known.future
    assert a[0] == pytest.approx([1.1, -1.6])                          # 0.2 s old at 0.5 m/s
    assert a[-1] == pytest.approx([1.2, 0.3])  # 4.2 s at 0.5 m/s: 0.2 m on, turned, 1.9 m up
    assert known.now[0, 4] == 1.0 and known.now[1, 4] == 0.0          # b holds: it stands
    assert np.allclose(b, b[0])
    assert d[-1] == pytest.approx([1.5, -4.0])                         # holds 0.5 m on
    assert known.now[0, 2:4] == pytest.approx([0.5, 0.0])              # along its path now


@pytest.fixture
def controller(cfg: Config) -> tuple[LocalController, PeopleStage]:
    robot = RobotModel.from_config(cfg.robot)
    ctrl = LocalController(cfg.nav.controller, robot, Costmap(open_grid(12.0), robot,
                                                               cfg.nav.costmap))
    ctrl.set_plan(straight_plan(-1.0, 4.0), Pose2D(4.0, 0.0, 0.0))
    stage = PeopleStage(cfg.people, cfg.nav.controller, robot, lambda: None)
    ctrl.people = stage
    return ctrl, stage


def _output_after(ctrl: LocalController, seconds: float) -> ControlOutput:
    out = None
    for k in range(int(seconds / ctrl.dt_s)):
        out = ctrl.compute(Pose2D(-1.0, 0.0, 0.0), k * ctrl.dt_s)
    assert out is not None
    return out


def test_the_controller_gives_way_to_where_the_rover_will_be(
        controller: tuple[LocalController, PeopleStage]) -> None:
    """The other rover drives parallel now but its plan crosses our lane in ~3.6 s: with its
    intent the controller bends at once to pass behind it; the same rover as a person track
    (constant velocity: it would pass by, 1.6 m aside) changes nothing."""
    ctrl, stage = controller
    table = PeerTable("me")
    table.update("a", TURNING)
    stage.movers = RoverIntent(table, lambda: 100.0, 2.0)
    with_intent = _output_after(ctrl, 1.0)
    assert stage.changed > 0 and with_intent.status is ControlStatus.AVOIDING
    assert with_intent.angular_radps < -0.1  # to the right: behind the other rover

    ctrl.reset()
    ctrl.set_plan(straight_plan(-1.0, 4.0), Pose2D(4.0, 0.0, 0.0))
    plain = PeopleStage(stage.cfg, stage.ccfg, stage.robot, lambda: PeopleTracks(
        math.inf, (PersonTrack(1, 1.0, -1.6, 0.5, 0.0, walked=True),)))
    plain.tracks = lambda: PeopleTracks(ctrl_now["t"], (PersonTrack(1, 1.0, -1.6, 0.5, 0.0,
                                                                    walked=True),))
    ctrl.people = plain
    ctrl_now = {"t": 0.0}
    out = None
    for k in range(int(1.0 / ctrl.dt_s)):
        ctrl_now["t"] = k * ctrl.dt_s
        out = ctrl.compute(Pose2D(-1.0, 0.0, 0.0), ctrl_now["t"])
    assert out is not None and plain.changed == 0
    assert out.status is ControlStatus.FOLLOWING and out.angular_radps == 0.0


def test_a_person_track_on_a_rover_counts_once_as_the_rover(
        controller: tuple[LocalController, PeopleStage]) -> None:
    _ctrl, stage = controller
    table = PeerTable("me")
    table.update("a", TURNING)
    stage.movers = RoverIntent(table, lambda: 100.0, 2.0)
    stage.tracks = lambda: PeopleTracks(0.0, (PersonTrack(1, 1.05, -1.6, 0.5, 0.0, walked=True),
                                              PersonTrack(2, 3.0, 2.0, 0.0, 0.0, walked=True)))
    rows = stage.people_near(Pose2D(-1.0, 0.0, 0.0), 0.0)
    assert rows.shape == (2, 6)
    assert rows[0, :2] == pytest.approx([3.0, 2.0]) and rows[0, 5] == 0.0
    assert rows[1, 5] == pytest.approx(0.45 - stage.cfg.person_radius_m)


def test_excuse_me_is_not_said_to_a_rover(
        controller: tuple[LocalController, PeopleStage]) -> None:
    """A rover standing across the lane: the controller waits, turns assertive after
    ``excuse_me_after_s``, but says nothing (nobody to say it to)."""
    ctrl, stage = controller
    said: list[str] = []
    stage.on_excuse_me.append(said.append)
    table = PeerTable("me")
    table.update("a", {**TURNING, "x": 0.2, "y": 0.0, "v": 0.0, "goal": False, "plan": []})
    stage.movers = RoverIntent(table, lambda: 100.0, 2.0)
    _output_after(ctrl, stage.cfg.excuse_me_after_s + 3.0)
    assert stage._assertive_until_s > 0 and said == [] and stage.excuse_me_count == 0


@pytest.mark.parametrize("predict", [False, True])
def test_the_wiring_feeds_the_people_stage_only_when_asked(tmp_path: Path, predict: bool
                                                          ) -> None:
    cfg = load_config(None, [f'data_dir="{tmp_path}"', "web.enabled=false",
                             "fleet.enabled=true", 'fleet.rover="r1"',
                             f"fleet.traffic.predict_peers={str(predict).lower()}"])
    app = App(cfg, SimClock(), web=False,
              fleet_transport=MemoryTransport("r1", MemoryNetwork()))
    assert app.people is not None and app.people.stage is not None and app.fleet is not None
    movers = app.people.stage.movers
    assert isinstance(movers, RoverIntent) is predict
    if isinstance(movers, RoverIntent):
        assert app.fleet.traffic is not None and movers.peers is app.fleet.traffic.peers
