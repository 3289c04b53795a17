"""The follow-path tree: each behaviour's status logic, every priority pre-emption, the operator
messages, and a test per fixed defect of the original (original-system.md §8–9).

Ticks are synchronous (``runner.tick()``) on a manual clock and a scripted fake navigator.
"""

from __future__ import annotations

import pytest
from py_trees.common import Status

from curio.bt.paths import Waypoint
from curio.core.config import BtConfig
from curio.core.topics import TREE

from .bt_fakes import make_harness


def start_path(h, path_id: int = 1) -> None:  # type: ignore[no-untyped-def]
    h.press("select_path", path_id=path_id)
    h.tick()


# --- start-up -------------------------------------------------------------------------------


def test_initial_blackboard() -> None:
    h = make_harness()
    h.tick()
    bb = h.runner.blackboard()
    assert bb["blocked"] is False  # §9.1–9.2: positively named, "not blocked" by default
    assert bb["paused"] is False and bb["estop"] is False
    assert bb["command"] is None and bb["home_request"] is None
    assert bb["curr_path"] is None and bb["waypoint"] == 0 and bb["phase"] == "idle"
    assert bb["help_active"] is False


def test_no_motion_at_start_up_without_a_command() -> None:
    h = make_harness()
    h.tick(10)
    assert h.nav.goals == []  # §9.16: the original drove path 1 at launch
    assert h.texts() == ["Idle"] and h.kinds("help") == []  # and asked for help (§2.3)


def test_autostart_only_when_configured() -> None:
    h = make_harness(BtConfig(speak=False, autostart_path=1))
    h.tick()
    assert h.nav.target() == (0.2, 0.0)
    assert h.texts()[-1] == "Moving to (0.2,0)"  # §9.8: built from the real waypoint
    bad = make_harness(BtConfig(speak=False, autostart_path=9))
    bad.tick()
    assert bad.nav.goals == [] and "There is no path 9" in bad.last_message(
        "bt.command_rejected")


def test_buttons_work_without_a_blocked_detector() -> None:
    # §9.2: with no BLOCKED publisher the original's Go Home and Pause stopped working.
    h = make_harness()
    start_path(h)
    h.press("pause")
    h.tick()
    assert h.status.state == "paused"
    h.press("resume")
    h.tick()
    h.press("go_home")
    h.tick()
    assert h.nav.target() == (0.0, 0.0) and h.status.text == "Going home"


def test_commands_apply_on_the_next_tick_every_tick() -> None:
    # §9.3: ToBlackboard refreshed a key every other tick and lost quick commands.
    h = make_harness()
    h.press("select_path", path_id=1)
    h.tick()
    assert h.nav.target() == (0.2, 0.0)
    h.press("select_path", path_id=2)
    h.tick()
    assert h.nav.target() == (1.0, 1.0)
    assert len(h.of("bt.command_accepted")) == 2


def test_a_later_command_in_the_same_tick_wins_and_the_earlier_is_answered() -> None:
    h = make_harness()
    h.press("select_path", path_id=1)
    h.press("select_path", path_id=2)
    h.tick()
    assert h.nav.target() == (1.0, 1.0) and len(h.nav.goals) == 1
    assert "Replaced by a later path command" in h.last_message("bt.command_rejected")


# --- follow path, idle ----------------------------------------------------------------------


def test_follow_path_status_logic() -> None:
    h = make_harness()
    follow = h.node("Follow Path")
    h.tick()
    assert follow.status == Status.FAILURE and h.node("Idle").status == Status.RUNNING
    start_path(h, 2)
    h.tick()
    assert follow.status == Status.RUNNING
    h.nav.succeed()
    h.tick()
    h.nav.succeed()
    h.tick()
    h.nav.succeed()
    h.tick()
    assert follow.status == Status.SUCCESS  # the tick the path finished
    h.tick()
    assert follow.status == Status.FAILURE and h.node("Idle").status == Status.RUNNING
    assert h.status.text == "Arrived at (3,4)" and h.status.state == "arrived"
    assert [s for p in h.progress[-1:] for s in p.states] == ["reached"] * 3
    assert [e.detail["index"] for e in h.of("waypoint.reached")] == [0, 1, 2]
    assert len(h.of("path.finished")) == 1


def test_unknown_path_is_rejected_and_nothing_changes() -> None:
    # §9.9: the original set curr_path = 0 without a goal and re-sent the bad id later.
    h = make_harness()
    start_path(h, 2)
    goal = h.nav.last
    h.press("select_path", path_id=7)
    h.tick()
    msg = h.last_message("bt.command_rejected")
    assert "There is no path 7" in msg and "1 (Path 1)" in msg
    assert h.nav.last is goal and not goal.done and h.bb("curr_path") == 2


def test_empty_and_missing_path_number_are_rejected() -> None:
    h = make_harness()
    h.paths.create("Empty")
    h.press("select_path", path_id=3)
    h.press("select_path")
    h.tick()
    rejected = [e.detail["message"] for e in h.of("bt.command_rejected")]
    assert rejected == ["Path 3 (Empty) has no waypoints yet; add some on the map first.",
                        "Choose a path number."]
    assert h.nav.goals == []


def test_clicked_long_path_with_headings_is_driven_to_the_end() -> None:
    h = make_harness()
    wps = [Waypoint(float(i), 0.0, None) for i in range(6)]
    pid = h.paths.create("Long", wps).id
    start_path(h, pid)
    for _ in range(6):
        h.nav.succeed()
        h.tick()
    assert len(h.of("waypoint.reached")) == 6 and h.of("path.finished")
    # A waypoint without a heading faces along the path.
    assert h.nav.goals[1].poses[0].yaw == pytest.approx(0.0)


def test_cancel_stops_the_route() -> None:
    h = make_harness()
    start_path(h)
    h.press("cancel")
    h.tick()
    assert h.nav.active is None and h.bb("phase") == "idle"
    assert h.last_message("bt.command_accepted") == "Stopped."
    assert h.status.text == "Idle"


def test_dashboard_goal_interrupts_the_path_and_idle_reports_it() -> None:
    from curio.core.geometry import Pose2D

    h = make_harness()
    start_path(h, 2)
    h.press("goto")
    h.nav.send_goal(Pose2D(4.0, 1.5, 0.0), tag="web")  # the navigator handles goto itself
    h.tick()
    assert "Leaving Path 2" in h.last_message("bt.command_accepted")
    h.tick()
    assert h.bb("phase") == "interrupted"
    assert h.status.text == "Moving to (4,1.5)"
    h.nav.succeed()
    h.tick()
    assert h.status.text == "Arrived at (4,1.5)"


# --- pause ----------------------------------------------------------------------------------


def test_pause_blocks_every_lower_branch() -> None:
    h = make_harness()
    start_path(h)
    h.press("pause")
    h.tick()
    assert h.node("Pause").status == Status.RUNNING
    assert h.node("Follow Path").status == Status.INVALID
    h.blocked(True)
    h.tick(5)
    assert h.kinds("help") == []  # lower priority than Pause
    assert h.bb("curr_path") == 1  # §9.10: pausing does not force path 1 / change the path


def test_toggle_twice_in_one_tick_counts_once() -> None:
    h = make_harness()
    start_path(h)
    h.press("toggle_pause")
    h.press("toggle_pause")
    h.tick()
    assert h.bb("paused") is True
    assert "counted once" in h.last_message("bt.command_rejected")
    h.press("toggle_pause")
    h.tick()
    assert h.bb("paused") is False and h.nav.active is not None


def test_go_home_while_paused_is_rejected_with_a_message() -> None:
    # §9.5: the original silently dropped it while the dashboard showed green.
    h = make_harness()
    start_path(h)
    h.press("pause")
    h.tick()
    h.press("go_home")
    h.tick()
    assert h.last_message("bt.command_rejected") == (
        "The rover is paused: press Resume first, then Go Home.")
    h.press("resume")
    h.tick(3)
    assert h.nav.target() == (0.2, 0.0)  # nothing was deferred


def test_path_command_while_paused_is_rejected_not_deferred() -> None:
    # §9.5: the original deferred it silently and applied it after resume.
    h = make_harness()
    start_path(h)
    h.press("pause")
    h.tick()
    h.press("select_path", path_id=2)
    h.tick()
    assert "press Resume first, then choose the path" in h.last_message("bt.command_rejected")
    h.press("resume")
    h.tick(2)
    assert h.bb("curr_path") == 1 and h.nav.target() == (0.2, 0.0)


def test_pause_and_resume_when_finished_does_not_restart() -> None:
    # §9.14: the original restarted a finished path from the beginning.
    h = make_harness()
    start_path(h, 2)
    for _ in range(3):
        h.nav.succeed()
        h.tick()
    goals = len(h.nav.goals)
    h.press("pause")
    h.tick()
    h.press("resume")
    h.tick(2)
    assert len(h.nav.goals) == goals
    assert "no route to continue" in h.last_message("bt.command_accepted")


def test_resume_when_not_paused_is_answered() -> None:
    h = make_harness()
    h.press("resume")
    h.press("pause")
    h.press("pause")
    h.tick()
    messages = [e.detail["message"] for e in h.of("bt.command_accepted")]
    assert messages == ["Paused."]  # resume then pause then pause: the last pause wins
    h.press("pause")
    h.tick()
    assert h.last_message("bt.command_accepted") == "Already paused."
    h.press("resume")
    h.tick()
    h.press("resume")
    h.tick()
    assert h.last_message("bt.command_accepted") == "The rover is not paused."


def test_goto_while_paused_is_cancelled_with_a_message() -> None:
    from curio.core.geometry import Pose2D

    h = make_harness()
    h.press("pause")
    h.tick()
    h.press("goto")
    foreign = h.nav.send_goal(Pose2D(1.0, 1.0, 0.0), tag="web")
    h.tick()
    assert foreign.state.value == "preempted"
    assert "Not moving: the rover is paused" in h.last_message("bt.command_rejected")


# --- go home --------------------------------------------------------------------------------


def test_go_home_sends_one_goal_per_press() -> None:
    # §9.4: the original published "0" on two ticks per press, re-sending the goal.
    h = make_harness()
    start_path(h, 2)
    h.press("go_home")
    h.tick(4)
    home_goals = [g for g in h.nav.goals if g.tag.startswith("path 0")]
    assert len(home_goals) == 1
    assert h.status.text == "Going home" and h.status.state == "going_home"
    h.press("go_home")
    h.tick()
    assert len([g for g in h.nav.goals if g.tag.startswith("path 0")]) == 1
    assert h.last_message("bt.command_accepted") == "Already going home."
    h.nav.succeed()
    h.tick()
    assert h.status.text == "Arrived at (0,0)"


def test_select_path_zero_is_go_home() -> None:
    h = make_harness()
    start_path(h, 2)
    h.press("select_path", path_id=0)
    h.tick()
    assert h.nav.target() == (0.0, 0.0) and h.bb("curr_path") == 0


def test_go_home_preempts_a_pending_path_command_in_order() -> None:
    h = make_harness()
    h.press("select_path", path_id=2)
    h.press("go_home")
    h.tick()
    assert h.nav.target() == (0.0, 0.0) and len(h.nav.goals) == 1
    h.press("go_home")
    h.press("select_path", path_id=2)
    h.tick()
    assert h.nav.target() == (1.0, 1.0)  # the later command wins


# --- help -----------------------------------------------------------------------------------


def block_and_ask(h):  # type: ignore[no-untyped-def]
    start_path(h, 2)
    h.blocked(True, 0.7)
    h.tick()


def test_ask4help_blocked_then_clear() -> None:
    h = make_harness(BtConfig(speak=False, help_clear_s=1.0))
    block_and_ask(h)
    goal = h.nav.goals[0]
    assert goal.state.value == "preempted" and h.nav.active is None
    req = h.of("help.requested")
    assert len(req) == 1 and req[0].detail["obstacle_distance_m"] == 0.7
    assert h.status.text == "Needs help" and h.bb("help_active") is True
    h.tick(10)
    assert len(h.of("help.requested")) == 1  # one request, held
    h.blocked(False)
    h.tick()  # clear for 0.5 s: not yet
    assert h.of("help.resolved") == []
    h.tick(2)
    resolved = h.of("help.resolved")
    assert len(resolved) == 1 and resolved[0].detail["message"] == "Thanks!"
    assert resolved[0].detail["reason"] == "clear"
    # Resumed at the same waypoint, and Follow Path ran in the same tick.
    assert h.nav.target() == (1.0, 1.0) and h.nav.active is not None
    assert h.node("Follow Path").status == Status.RUNNING
    assert h.status.text == "Moving to (1,1)" and h.bb("help_active") is False


def test_blocked_flicker_does_not_drop_the_request() -> None:
    h = make_harness(BtConfig(speak=False, help_clear_s=2.0))
    block_and_ask(h)
    for flag in (False, True, False, True):
        h.blocked(flag)
        h.tick()
    assert h.of("help.resolved") == [] and h.node("Ask4Help").status == Status.RUNNING


def test_never_asks_at_a_reached_goal() -> None:
    # §9.24: a rover standing at its goal next to a wall is not stuck.
    h = make_harness()
    start_path(h, 2)
    for _ in range(3):
        h.nav.succeed()
        h.tick()
    h.blocked(True)
    h.tick(10)
    assert h.kinds("help") == []
    # ... nor when idle, paused or e-stopped.
    h.press("pause")
    h.tick(3)
    assert h.kinds("help") == []


def test_help_done_resolves_and_rearms() -> None:
    h = make_harness(BtConfig(speak=False, help_rearm_s=10.0))
    block_and_ask(h)
    h.press("help_done")
    h.tick()
    assert h.of("help.resolved")[-1].detail["reason"] == "help_done"
    assert h.last_message("bt.command_accepted") == "Thanks!"
    assert h.nav.active is not None  # resumed
    h.tick(10)  # still flagged (the rover has not moved yet): no new request for 10 s
    assert len(h.of("help.requested")) == 1
    h.tick(12)
    assert len(h.of("help.requested")) == 2  # after the re-arm delay it asks again


def test_rearm_ends_when_the_detector_reports_clear() -> None:
    h = make_harness(BtConfig(speak=False, help_rearm_s=100.0))
    block_and_ask(h)
    h.press("help_done")
    h.tick()
    h.blocked(False)
    h.tick()
    h.blocked(True)
    h.tick()
    assert len(h.of("help.requested")) == 2  # a new blocked episode


def test_help_done_without_a_request_is_rejected() -> None:
    h = make_harness()
    h.press("help_done")
    h.tick()
    assert h.last_message("bt.command_rejected") == "The rover is not waiting for help."


@pytest.mark.parametrize("action", ["replan", "go_home", "keep_waiting"])
def test_help_timeout_actions(action: str) -> None:
    # §9.25: the original could stay paused for ever next to a static structure.
    h = make_harness(BtConfig(speak=False, help_timeout_s=5.0, help_timeout_action=action))
    block_and_ask(h)
    h.tick(9)
    assert h.of("help.resolved") == [] and h.of("help.timeout") == []
    h.tick(2)
    if action == "replan":
        assert h.of("help.resolved")[0].detail["reason"] == "timeout"
        assert "trying another route" in h.last_message("help.resolved")
        assert h.nav.target() == (1.0, 1.0) and h.nav.active is not None
    elif action == "go_home":
        assert "going home" in h.last_message("help.resolved")
        assert h.nav.target() == (0.0, 0.0) and h.status.text == "Going home"
    else:
        assert h.of("help.resolved") == [] and len(h.of("help.timeout")) == 1
        h.tick(20)
        assert len(h.of("help.timeout")) == 1 and h.status.text == "Needs help"


# --- pre-emption by priority ----------------------------------------------------------------


def test_pause_preempts_help_and_withdraws_the_request() -> None:
    h = make_harness()
    block_and_ask(h)
    h.press("pause")
    h.tick()
    assert h.node("Ask4Help").status == Status.INVALID
    last = h.of("help.resolved")[-1]
    assert last.detail["reason"] == "preempted" and last.detail["message"] != "Thanks!"
    assert h.bb("help_active") is False and h.status.text == "Paused"


def test_go_home_preempts_help() -> None:
    h = make_harness()
    block_and_ask(h)
    h.press("go_home")
    h.tick()
    assert h.of("help.resolved")[-1].detail["reason"] == "preempted"
    assert h.nav.target() == (0.0, 0.0) and h.nav.active is not None
    h.tick(3)
    assert len(h.of("help.requested")) == 1  # re-armed: no immediate second request


def test_path_command_preempts_help() -> None:
    h = make_harness()
    block_and_ask(h)
    h.press("select_path", path_id=1)
    h.tick()
    assert h.of("help.resolved")[-1].detail["reason"] == "preempted"
    assert h.bb("curr_path") == 1 and h.nav.active is not None


def test_estop_preempts_pause_and_release_stays_paused() -> None:
    h = make_harness()
    start_path(h)
    h.nav.succeed()
    h.tick()
    h.estop(True)
    h.tick()
    assert h.status.state == "estop" and h.nav.active is None
    assert h.node("Hold (e-stop)").status == Status.RUNNING
    h.press("select_path", path_id=2)
    h.press("go_home")
    h.press("resume")
    h.tick()
    assert len(h.of("bt.command_rejected")) == 3
    assert all("e-stop is engaged" in e.detail["message"] for e in h.of("bt.command_rejected"))
    h.estop(False)
    h.tick()
    assert h.status.text == "Paused" and h.bb("paused") is True
    assert "press Resume" in h.last_message("bt.estop_released")
    h.press("resume")
    h.tick()
    assert h.nav.target() == (-0.2, 0.0)  # same waypoint as before the e-stop


def test_operator_estop_engages_before_the_safety_stage_answers() -> None:
    h = make_harness()
    start_path(h)
    h.press("estop")
    h.tick()
    assert h.bb("estop") is True and h.nav.active is None
    h.press("release_estop")  # no safety stage in this test: the release is ours to apply
    h.tick()
    assert h.bb("estop") is False and h.bb("paused") is True


def test_estop_preempts_help() -> None:
    h = make_harness()
    block_and_ask(h)
    h.estop(True)
    h.tick()
    assert h.of("help.resolved")[-1].detail["reason"] == "preempted"
    assert h.status.state == "estop"


# --- tick rate, snapshots, blackboard discipline --------------------------------------------


def test_works_at_20_hz_with_times_in_seconds() -> None:
    h = make_harness(BtConfig(speak=False, tick_hz=20.0, help_clear_s=1.0))
    assert h.runner.period_s == pytest.approx(0.05)
    block_and_ask(h)
    h.blocked(False)
    h.tick(19)  # 0.95 s
    assert h.of("help.resolved") == []
    h.tick(2)
    assert len(h.of("help.resolved")) == 1


def test_tree_snapshot_only_when_something_changed() -> None:
    h = make_harness()
    sub = h.bus.subscribe(TREE)
    h.tick()
    first = sub.drain()
    assert len(first) == 1
    snap = first[0]
    names = [n["name"] for n in snap.nodes]
    assert names[:2] == ["Root", "Operator2BB"] and "Ask4Help" in names
    root = snap.nodes[0]
    assert root["parent"] is None and root["type"] == "Parallel"
    for node in snap.nodes:
        for child in node["children"]:
            assert snap.nodes[child]["parent"] == node["id"]
    assert snap.blackboard["blocked"] is False
    h.tick(3)
    assert sub.drain() == []  # nothing changed
    start_path(h)
    changed = sub.drain()
    assert len(changed) == 1 and changed[0].blackboard["curr_path"] == 1
    assert h.runner.snapshot() is changed[0]


def test_blackboard_access_is_declared() -> None:
    h = make_harness()
    is_blocked = h.node("Blocked?")
    with pytest.raises(AttributeError):
        is_blocked.bb.blocked = True  # READ only
    with pytest.raises(AttributeError):
        is_blocked.bb.get("paused")  # not declared at all


def test_two_trees_do_not_share_a_blackboard() -> None:
    a = make_harness()
    b = make_harness()
    start_path(a)
    b.tick()
    assert a.bb("curr_path") == 1 and b.bb("curr_path") is None


async def test_close_interrupts_and_cancels() -> None:
    h = make_harness()
    start_path(h)
    await h.runner.close()
    assert h.nav.active is None and h.nav.cancels >= 1
    assert h.node("Root").status == Status.INVALID


async def test_runner_ticks_on_the_injected_clock() -> None:
    import asyncio

    from curio.bt.paths import PathManager
    from curio.bt.runner import build_tree_runner
    from curio.core.clock import SimClock
    from curio.core.topics import make_bus

    from .bt_fakes import FakeNavigator

    clock = SimClock()
    bus = make_bus()
    cfg = BtConfig(speak=False, tick_hz=2.0)
    runner = build_tree_runner(cfg, bus, clock, FakeNavigator(), PathManager(cfg.paths, None))
    task = asyncio.create_task(runner.run())
    await clock.advance(10.0)
    task.cancel()
    await runner.close()
    assert runner.tick_count == 21  # t = 0, 0.5, ..., 10.0


# --- help when the navigator gives up, and the way probe ------------------------------------


class FakeProbe:
    """Answers "is there a path now?" from a flag the test sets (plans nothing)."""

    def __init__(self) -> None:
        self.clear = False
        self.starts: list[tuple[float, float]] = []
        self.last = None
        self.busy = False

    def start(self, goal, now_s):  # type: ignore[no-untyped-def]
        from curio.bt.probe import ProbeResult

        self.starts.append((goal.x, goal.y))
        self.last = ProbeResult(now_s, self.clear, "" if self.clear else "no path")
        return True

    def poll(self):  # type: ignore[no-untyped-def]
        return self.last

    def reset(self) -> None:
        self.last = None


def probe_harness(**cfg):  # type: ignore[no-untyped-def]
    h = make_harness(BtConfig(speak=False, **cfg))
    probe = FakeProbe()
    h.runner.ctx.probe = probe  # type: ignore[assignment]
    return h, probe


def test_aborted_for_no_path_asks_for_help_and_resumes_when_a_path_exists() -> None:
    h, probe = probe_harness(help_clear_s=1.0)
    start_path(h, 2)
    h.nav.abort()  # NoPathError after the navigator's recovery ladder
    h.tick()
    h.tick()
    req = h.of("help.requested")
    assert len(req) == 1 and req[0].detail["trigger"] == "no_path"
    assert h.status.text == "Needs help"
    h.tick(6)
    assert probe.starts and probe.starts[-1] == (1.0, 1.0)  # probing the held waypoint
    assert h.of("help.resolved") == []  # BLOCKED says nothing; the probe finds no path
    probe.clear = True
    h.tick(2)
    assert h.of("help.resolved") == []  # clear for 0.5 s only
    h.tick(2)
    assert h.last_message("help.resolved") == "Thanks!"
    assert h.nav.target() == (1.0, 1.0) and h.nav.active is not None


def test_probe_must_stay_clear_for_the_whole_window() -> None:
    h, probe = probe_harness(help_clear_s=2.0)
    block_and_ask(h)
    for clear in (True, True, False, True, True, True):
        probe.clear = clear
        h.tick()
    assert h.of("help.resolved") == []
    h.tick(2)
    assert len(h.of("help.resolved")) == 1


def test_unreachable_goal_is_not_a_help_case() -> None:
    from curio.nav.api import GoalOutsideMapError

    h, _ = probe_harness()
    start_path(h, 2)
    h.nav.abort(GoalOutsideMapError("The goal is outside the map."))
    h.tick(4)
    assert h.kinds("help") == [] and h.bb("phase") == "failed"


def test_resume_while_asking_for_help_means_help_done() -> None:
    h = make_harness()
    block_and_ask(h)
    h.press("resume")
    h.tick()
    assert h.of("help.resolved")[-1].detail["reason"] == "help_done"
    assert h.nav.active is not None


def test_final_tree_structure_and_priorities() -> None:
    # §8 item 3: the original's final tree, with the e-stop guard on top.
    h = make_harness()
    h.tick()
    snap = h.runner.snapshot()
    by_id = {n["id"]: n for n in snap.nodes}
    root = snap.nodes[0]
    assert [by_id[c]["name"] for c in root["children"]] == [
        "Operator2BB", "Blocked2BB", "EStop2BB", "Battery2BB", "Goal2BB", "Localization2BB",
        "Dock2BB", "Priorities"]
    prio = next(n for n in snap.nodes if n["name"] == "Priorities")
    assert prio["type"] == "Selector"
    # Issue 11: the battery and lost-and-found branches sit under E-stop and Pause in every
    # tree (with a dock, Dock, Undock and Docked join them: test_unattended_bt.py).
    assert [by_id[c]["name"] for c in prio["children"]] == [
        "E-stop", "Pause", "Battery critical", "Lost", "Battery", "Go Home", "Change Path?",
        "Check Path", "Follow Path", "Idle"]
    check = next(n for n in snap.nodes if n["name"] == "Check Path")
    assert [by_id[c]["name"] for c in check["children"]] == ["Blocked?", "Ask4Help"]


@pytest.mark.parametrize("path_id", [-1, -2, 3, 99])
def test_negative_and_unknown_ids_are_rejected(path_id: int) -> None:
    # §9.11: "-2" raised a KeyError inside the original's path follower.
    h = make_harness()
    h.press("select_path", path_id=path_id)
    h.tick()
    assert f"There is no path {path_id}" in h.last_message("bt.command_rejected")
    assert h.nav.goals == [] and h.bb("curr_path") is None


def test_commands_are_not_replayed_after_a_restart() -> None:
    # §9.18: the original's latched switch_path replayed the last command ("-1") on restart.
    from curio.core.topics import OPERATOR

    assert OPERATOR.kind == "reliable" and not OPERATOR.latched
    h = make_harness()
    h.press("select_path", path_id=1)
    h.tick()
    again = make_harness(bus=h.bus)  # a new tree on the same bus
    again.tick(3)
    assert again.nav.goals == []
