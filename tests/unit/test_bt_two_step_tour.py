"""The simple two-step tree, the tour guide (stops, dwell, messages, loop, low battery with
hysteresis, e-stop over everything), the speaker and the way probe on a real planner."""

from __future__ import annotations

import os
import shutil

import pytest
from py_trees.common import Status

from curio.bt.probe import WayProbe
from curio.bt.speech import Speaker
from curio.core.config import BtConfig, TourStopConfig
from curio.robot import RobotModel

from .bt_fakes import make_harness

# --- two-step --------------------------------------------------------------------------------


def two_step():  # type: ignore[no-untyped-def]
    return make_harness(BtConfig(speak=False, tree="two_step",
                                 two_step_goals=[(1.0, 1.0, 1.57), (1.0, 5.0, 0.0)]))


def test_two_step_patrols_for_ever() -> None:
    h = two_step()
    h.tick()
    targets = []
    for _ in range(5):
        targets.append(h.nav.target())
        h.nav.succeed()
        h.tick()
        h.tick()  # the patrol sequence restarts on the tick after it succeeded
    assert targets == [(1.0, 1.0), (1.0, 5.0), (1.0, 1.0), (1.0, 5.0), (1.0, 1.0)]
    assert h.texts()[:3] == ["Moving to (1,1)", "Arrived at (1,1)", "Moving to (1,5)"]


def test_two_step_go_home_preempts_then_patrol_restarts_from_goal_one() -> None:
    h = two_step()
    h.tick()
    h.nav.succeed()
    h.tick()  # heading to goal 2
    patrol_goal = h.nav.last
    h.press("go_home")
    h.tick()
    assert h.nav.target() == (0.0, 0.0)
    assert patrol_goal.state.value == "preempted"
    assert h.of("goal.preempted") and h.status.text == "Going home"
    assert h.last_message("bt.command_accepted") == "Going home."
    h.tick(3)  # the Go Home branch keeps running without re-checking its guard
    assert h.node("MoveRobot Home").status == Status.RUNNING and len(h.nav.goals) == 3
    h.nav.succeed()
    h.tick()
    assert h.status.text == "Arrived at (0,0)"
    h.tick()
    assert h.nav.target() == (1.0, 1.0)  # the patrol restarts from goal 1


def test_two_step_failure_does_not_storm_goals() -> None:
    h = two_step()
    h.tick()
    h.nav.abort()
    h.tick(6)  # 3 s: within the 5 s retry delay
    assert len(h.nav.goals) == 1 and h.status.text.startswith("Could not reach (1,1)")
    h.tick(6)
    assert len(h.nav.goals) == 2


def test_two_step_estop_and_pause() -> None:
    h = two_step()
    h.tick()
    h.estop(True)
    h.tick()
    assert h.nav.active is None and h.status.state == "estop"
    h.estop(False)
    h.tick()
    h.press("pause")
    h.tick()
    assert h.status.text == "Paused"


def test_two_step_refuses_route_commands() -> None:
    h = two_step()
    h.tick()
    for action in ("select_path", "cancel", "start_tour"):
        h.press(action, path_id=1 if action == "select_path" else None)
    h.tick()
    rejected = h.of("bt.command_rejected")
    assert len(rejected) == 3 and all("two-step tree" in e.detail["message"] for e in rejected)
    assert len(h.nav.goals) == 1


# --- tour -----------------------------------------------------------------------------------


STOPS = [TourStopConfig(name="Lobby", x_m=1.0, y_m=0.0, dwell_s=2.0, message="Welcome!"),
         TourStopConfig(name="Gallery", x_m=5.0, y_m=1.0, yaw_deg=90.0, dwell_s=1.0,
                        message="The gallery."),
         TourStopConfig(name="Lab", x_m=8.0, y_m=2.0, dwell_s=0.0, message="")]


def tour(**kw):  # type: ignore[no-untyped-def]
    cfg = BtConfig(speak=False, tree="tour", tour_stops=STOPS, **kw)
    return make_harness(cfg)


def test_tour_stops_dwell_and_announce() -> None:
    h = tour()
    h.press("start_tour")
    h.tick()
    assert h.nav.target() == (1.0, 0.0) and h.status.text == "Moving to (1,0)"
    assert h.status.state == "tour"
    assert h.last_message("bt.command_accepted") == "Tour started: 3 stops."
    h.nav.succeed()
    h.tick()
    stop = h.of("tour.stop")[0]
    assert stop.detail["name"] == "Lobby" and stop.detail["message"] == "Welcome!"
    assert h.status.text == "At Lobby: Welcome!" and h.speaker.spoken == ["Welcome!"]
    h.tick(3)  # 1.5 s of the 2 s dwell
    assert len(h.nav.goals) == 1
    h.tick()
    assert h.nav.target() == (5.0, 1.0)
    assert h.nav.last.poses[0].yaw == pytest.approx(1.5708, abs=1e-3)
    h.nav.succeed()
    h.tick(3)
    h.nav.succeed()
    h.tick()
    assert [e.detail["name"] for e in h.of("tour.stop")] == ["Lobby", "Gallery", "Lab"]
    h.tick()  # the last stop's (zero) dwell ends
    assert len(h.of("path.finished")) == 1 and h.bb("phase") == "finished"


def test_tour_pause_during_dwell_keeps_the_remaining_dwell() -> None:
    h = tour()
    h.press("start_tour")
    h.tick()
    h.nav.succeed()
    h.tick()  # dwelling 2 s from t = 1.0
    h.press("pause")
    h.tick(10)
    h.press("resume")
    h.tick()  # 1.5 s of dwell remain
    h.tick(2)
    assert len(h.nav.goals) == 1
    h.tick(2)
    assert h.nav.target() == (5.0, 1.0)


def test_tour_loops_when_configured() -> None:
    h = tour(tour_loop=True)
    h.press("start_tour")
    h.tick()
    for _ in range(3):
        h.nav.succeed()
        h.tick(6)
    assert h.nav.target() == (1.0, 0.0) and h.of("tour.loop")


def test_tour_skips_an_unreachable_stop_but_asks_for_help_when_blocked() -> None:
    from curio.nav.api import GoalOutsideMapError

    h = tour()
    h.press("start_tour")
    h.tick()
    h.nav.abort(GoalOutsideMapError("The goal is outside the map."))
    h.tick()
    assert h.nav.target() == (5.0, 1.0)  # skipped, the tour goes on
    h.nav.abort()  # no path: a person may clear the way
    h.tick(2)
    assert h.of("help.requested") and h.status.text == "Needs help"


def test_tour_commands_are_checked() -> None:
    h = tour()
    h.press("stop_tour")
    h.tick()
    assert h.last_message("bt.command_rejected") == "No tour is running."
    h.press("start_tour")
    h.tick()
    h.press("stop_tour")
    h.tick()
    assert h.last_message("bt.command_accepted") == "Tour stopped."
    assert h.nav.active is None and h.status.text == "Tour stopped"
    plain = make_harness()
    plain.press("start_tour")
    plain.tick()
    assert "no tour" in plain.last_message("bt.command_rejected")
    empty = make_harness(BtConfig(speak=False, tree="tour"))
    empty.press("start_tour")
    empty.tick()
    assert "No tour stops" in empty.last_message("bt.command_rejected")


def test_low_battery_goes_home_once_with_hysteresis() -> None:
    # §9.7: the original's mock battery pinned the rover to the home path at 5 Hz.
    h = tour(low_battery_v=6.6, battery_ok_v=7.0)
    h.battery(7.4)
    h.press("start_tour")
    h.tick()
    h.battery(6.5)
    h.tick()
    assert h.nav.target() == (0.0, 0.0) and h.status.text == "Going home"
    assert h.of("battery.low")[0].detail["voltage_v"] == 6.5
    h.battery(6.7)  # above low, below ok: still low
    h.tick(4)
    assert len([g for g in h.nav.goals if g.tag.startswith("path 0")]) == 1
    h.press("start_tour")
    h.tick()
    assert "battery is low (6.70 V)" in h.last_message("bt.command_rejected")
    h.press("go_home")  # the operator may still send it home
    h.tick()
    assert h.last_message("bt.command_accepted") == "Already going home."
    h.battery(7.1)
    h.tick()
    assert h.of("battery.ok")
    h.press("start_tour")
    h.tick()
    assert h.nav.target() == (1.0, 0.0)


def test_estop_preempts_everything_in_the_tour() -> None:
    h = tour()
    h.press("start_tour")
    h.tick()
    h.battery(6.0)
    h.estop(True)
    h.tick()
    assert h.status.state == "estop" and h.nav.active is None
    assert h.node("Battery Home").status == Status.INVALID
    h.estop(False)
    h.tick()
    assert h.status.text == "Paused"


# --- speaker, probe ---------------------------------------------------------------------------


async def test_speaker_never_blocks_and_keeps_only_the_newest() -> None:
    sp = Speaker(enabled=True, program="true")  # stands in for espeak-ng
    assert sp.available
    sp.say("one")
    sp.say("two")
    sp.say("three")  # said while nothing has played yet: only the newest waits
    assert sp.played == []  # say() returned at once
    assert sp._task is not None
    await sp._task
    assert sp.played == ["three"] and sp.spoken == ["one", "two", "three"]
    await sp.close()
    off = Speaker(enabled=False)
    off.say("x")
    assert not off.available and off.spoken == ["x"] and off.played == []


@pytest.mark.skipif(not os.environ.get("CI") and shutil.which("espeak-ng") is None,
                    reason="espeak-ng not installed (scripts/test installs it)")
async def test_espeak_ng_speaks() -> None:  # pragma: no cover - depends on the machine
    sp = Speaker(enabled=True)
    sp.say("Hello")
    assert sp._task is not None
    await sp.close()


async def test_way_probe_on_a_real_planner() -> None:
    import numpy as np

    from curio.core.clock import SimClock
    from curio.core.config import Config
    from curio.core.geometry import Pose2D
    from curio.core.messages import PoseWithCovariance
    from curio.core.topics import POSE, make_bus
    from curio.estimation.maps import OccupancyGrid
    from curio.nav.costmap import Costmap
    from curio.nav.planner import GlobalPlanner

    cfg = Config()
    data = np.zeros((80, 80), dtype=np.int8)
    data[:, 39:41] = 100  # a wall across the room...
    data[45:75, 39:41] = 0  # ... with a 1.5 m doorway
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0), name="t")
    costmap = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    bus = make_bus()
    bus.publish(POSE, PoseWithCovariance(0.0, Pose2D(1.0, 1.0, 0.0)))
    probe = WayProbe(GlobalPlanner(cfg.nav.planner), costmap, bus, SimClock())
    assert probe.start(Pose2D(3.0, 1.0, 0.0), 1.0)
    assert probe.poll() is not None and probe.poll().clear  # type: ignore[union-attr]
    data[45:75, 39:41] = 100  # the door closes
    closed = Costmap(OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0), name="t"),
                     RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    probe.costmap = closed
    probe.start(Pose2D(3.0, 1.0, 0.0), 2.0)
    result = probe.poll()
    assert result is not None and not result.clear and result.started_s == 2.0


def test_pause_holds_a_low_battery_go_home_until_resume() -> None:
    h = tour()
    h.battery(7.4)
    h.press("start_tour")
    h.tick()
    h.press("pause")
    h.tick()
    h.battery(6.5)  # low, not critical (bt.critical_battery_v = 6.3 stops the rover instead)
    h.tick(4)
    assert h.status.text == "Paused" and h.nav.active is None  # Pause outranks Battery
    assert h.bb("battery_home_pending") is True
    h.press("resume")
    h.tick(2)
    assert h.nav.target() == (0.0, 0.0) and h.status.text == "Going home"
    assert h.bb("battery_home_pending") is False


def test_change_path_status_when_the_path_vanished() -> None:
    h = make_harness()
    h.paths.create("Doomed", [])
    h.paths.add_waypoint(3, 1.0, 1.0)
    h.press("select_path", path_id=3)
    h.runner.operator_feed.update()  # validated now...
    h.paths.delete(3)  # ... deleted before the tree applies it
    h.tick()
    assert h.node("Change Path").status == Status.FAILURE
    assert "There is no path 3" in h.last_message("bt.command_rejected")
    assert h.nav.goals == []
