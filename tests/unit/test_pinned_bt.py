"""Pinned: behaviour-tree behaviour that only slow integration tests (or nothing) caught.

Written before the behaviour-tree refactor so that it cannot change it by accident. Ticks are
synchronous on the manual clock and the scripted fake navigator of ``bt_fakes``; time steps
are exact binary fractions (0.25 s) so the boundaries are exact.

* **MoveClient** (the two-step tree's navigation client) cancels its own goal when it is
  pre-empted or the tree is closed, leaves alone a goal that already replaced its own, and
  re-sends a failed goal only after ``retry_s`` = 5 s.
* **Pause keeps the current path** (so far pinned only by the operator-demo scenario): the
  goal is cancelled, the route, the waypoint and the progress are kept, nothing is sent while
  paused, and Resume sends the same waypoint again and finishes the path.
* **Help timings at their defaults** (``bt.help_clear_s`` = 1 s since issue 11: the way is
  now judged from fresh scans, and a door that opens must be noticed within 3 s;
  ``bt.help_rearm_s`` = 15 s, ``bt.help_timeout_s`` = 120 s): each just before and at its
  boundary.
"""

from __future__ import annotations

from py_trees.common import Status

from curio.core.config import BtConfig
from curio.nav.api import GoalState

from .bt_fakes import Harness, make_harness

DT = 0.25  # an exact binary fraction: the clock lands exactly on every boundary


def two_step() -> Harness:
    return make_harness(BtConfig(speak=False, tree="two_step",
                                 two_step_goals=[(1.0, 1.0, 1.57), (1.0, 5.0, 0.0)]))


# --- MoveClient -----------------------------------------------------------------------------


def test_move_client_cancels_its_goal_when_preempted() -> None:
    h = two_step()
    h.tick(dt=DT)
    client = h.node("MoveRobot 1")
    goal = h.nav.last
    assert client.status == Status.RUNNING and h.nav.active is goal
    client.stop(Status.INVALID)  # what a higher-priority branch does to it
    h.collect()
    assert h.nav.cancels == 1
    assert goal.state is GoalState.PREEMPTED and h.nav.active is None
    (event,) = h.of("goal.preempted")
    assert event.detail["name"] == "MoveRobot 1"
    assert (event.detail["x_m"], event.detail["y_m"]) == (1.0, 1.0)


async def test_closing_the_two_step_tree_cancels_the_patrol_goal() -> None:
    h = two_step()
    h.tick(dt=DT)
    h.nav.succeed()
    h.tick(dt=DT)  # heading to goal 2
    goal = h.nav.last
    assert h.nav.target() == (1.0, 5.0) and h.nav.active is goal
    await h.runner.close()
    assert goal.state is GoalState.PREEMPTED and h.nav.active is None
    assert h.nav.cancels >= 1


def test_move_client_leaves_alone_the_goal_that_replaced_its_own() -> None:
    h = two_step()
    h.tick(dt=DT)
    patrol_goal = h.nav.last
    h.press("go_home")
    h.tick(dt=DT)
    home_goal = h.nav.last
    assert patrol_goal.state is GoalState.PREEMPTED
    assert h.of("goal.preempted")  # the patrol client noticed it was pre-empted ...
    assert h.nav.cancels == 0  # ... and did not cancel the home goal that replaced it
    assert home_goal.state is GoalState.ACTIVE and h.nav.active is home_goal
    assert h.nav.target() == (0.0, 0.0)


def test_move_client_resends_a_failed_goal_after_5_s_not_before() -> None:
    h = two_step()
    h.tick(dt=DT)
    h.nav.abort()
    h.tick(dt=DT)  # the client sees the failure now
    failed_at = h.clock.now()
    assert h.status.text.startswith("Could not reach (1,1)")
    h.tick(19, dt=DT)  # 4.75 s later
    assert h.clock.now() - failed_at == 4.75
    assert len(h.nav.goals) == 1
    h.tick(dt=DT)  # 5.0 s later
    assert len(h.nav.goals) == 2 and h.nav.target() == (1.0, 1.0)
    assert h.nav.active is h.nav.last


# --- Pause keeps the current path -----------------------------------------------------------


def test_pause_keeps_the_current_path_and_resume_drives_the_same_waypoint() -> None:
    h = make_harness()
    h.press("select_path", path_id=2)  # (1,1) -> (2,2) -> (3,4)
    h.tick(dt=DT)
    h.nav.succeed()
    h.tick(dt=DT)  # reached (1,1), heading to (2,2)
    leg = h.nav.last
    assert h.nav.target() == (2.0, 2.0) and leg.tag == "path 2 wp 1"
    h.clear()

    h.press("pause")
    h.tick(dt=DT)
    assert h.last_message("bt.command_accepted") == "Paused."
    assert leg.state is GoalState.PREEMPTED and h.nav.active is None  # the rover stops
    assert h.status.text == "Paused" and h.status.state == "paused"
    assert (h.bb("curr_path"), h.bb("waypoint"), h.bb("phase")) == (2, 1, "held")
    assert h.bb("paused") is True
    last = h.progress[-1]
    assert (last.path_id, last.current_index) == (2, 1)
    assert last.states == ("reached", "pending", "pending")  # nothing skipped or failed
    goals = len(h.nav.goals)
    h.tick(20, dt=DT)  # 5 s paused: nothing is sent, nothing changes
    assert len(h.nav.goals) == goals and h.nav.active is None
    assert (h.bb("curr_path"), h.bb("waypoint"), h.bb("phase")) == (2, 1, "held")
    assert h.progress[-1].states == ("reached", "pending", "pending")

    h.press("resume")
    h.tick(dt=DT)
    assert h.last_message("bt.command_accepted") == "Resumed."
    resumed = h.nav.last
    assert resumed is not leg and h.nav.active is resumed
    assert h.nav.target() == (2.0, 2.0) and resumed.tag == "path 2 wp 1"
    assert (h.bb("curr_path"), h.bb("waypoint"), h.bb("phase")) == (2, 1, "moving")
    assert h.progress[-1].states == ("reached", "active", "pending")
    assert h.status.text == "Moving to (2,2)"
    assert h.of("path.started") == []  # resumed, not restarted
    h.nav.succeed()
    h.tick(dt=DT)
    assert h.nav.target() == (3.0, 4.0)
    h.nav.succeed()
    h.tick(dt=DT)
    (finished,) = h.of("path.finished")
    assert finished.detail["path_id"] == 2 and finished.detail["reached"] == 3
    assert [e.detail["index"] for e in h.of("waypoint.reached")] == [1, 2]
    assert h.progress[-1].states == ("reached", "reached", "reached")


def test_pause_and_resume_at_the_first_waypoint_keep_it() -> None:
    h = make_harness()
    h.press("select_path", path_id=2)
    h.tick(dt=DT)
    first = h.nav.last
    h.press("pause")
    h.tick(dt=DT)
    assert first.state is GoalState.PREEMPTED
    assert (h.bb("curr_path"), h.bb("waypoint")) == (2, 0)
    assert h.progress[-1].states == ("pending", "pending", "pending")
    h.press("resume")
    h.tick(dt=DT)
    assert h.nav.target() == (1.0, 1.0) and h.nav.last.tag == "path 2 wp 0"
    assert h.progress[-1].states == ("active", "pending", "pending")


# --- help timings at their defaults ---------------------------------------------------------


def ask_for_help(h: Harness) -> float:
    """Drive path 2, get blocked, and return the time help was requested."""
    h.press("select_path", path_id=2)
    h.tick(dt=DT)
    h.blocked(True, 0.7)
    h.tick(dt=DT)
    assert len(h.of("help.requested")) == 1
    return h.clock.now()


def test_help_resolves_after_the_way_stays_clear_for_1_s() -> None:
    h = make_harness()
    ask_for_help(h)
    h.blocked(False)
    h.tick(dt=DT)  # first seen clear
    clear_since = h.clock.now()
    h.tick(3, dt=DT)
    assert h.clock.now() - clear_since == 0.75
    assert h.of("help.resolved") == [] and h.status.text == "Needs help"
    h.tick(dt=DT)  # clear for 1.0 s
    (resolved,) = h.of("help.resolved")
    assert resolved.detail["reason"] == "clear" and resolved.detail["message"] == "Thanks!"
    assert h.nav.active is not None and h.nav.target() == (1.0, 1.0)


def test_help_done_ignores_blocked_for_15_s() -> None:
    h = make_harness()
    ask_for_help(h)
    h.press("help_done")
    h.tick(dt=DT)  # resumed; BLOCKED still says blocked (the rover has not moved yet)
    done_at = h.clock.now()
    assert h.of("help.resolved")[-1].detail["reason"] == "help_done"
    h.tick(59, dt=DT)
    assert h.clock.now() - done_at == 14.75
    assert len(h.of("help.requested")) == 1 and h.nav.active is not None
    h.tick(dt=DT)  # 15 s: the re-arm delay is over
    assert len(h.of("help.requested")) == 2 and h.status.text == "Needs help"


def test_help_times_out_after_120_s() -> None:
    h = make_harness()  # help_timeout_action = replan
    asked_at = ask_for_help(h)
    h.tick(119, dt=1.0)
    h.tick(3, dt=DT)
    assert h.clock.now() - asked_at == 119.75
    assert h.of("help.resolved") == [] and h.status.text == "Needs help"
    h.tick(dt=DT)  # 120 s
    (resolved,) = h.of("help.resolved")
    assert resolved.detail["reason"] == "timeout"
    assert "No help came in 120 s" in resolved.detail["message"]
    assert h.nav.active is not None and h.nav.target() == (1.0, 1.0)  # replanning
