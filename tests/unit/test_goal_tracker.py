"""Goal tracking: handle states, waypoints, feedback and the goal events."""

from __future__ import annotations

import pytest

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.geometry import Pose2D
from curio.core.topics import EVENTS
from curio.nav.api import GoalState, NoPathError
from curio.nav.navigator.goals import GoalTracker


@pytest.fixture
def tracker(bus: Bus) -> GoalTracker:
    return GoalTracker(SimClock(start_s=100.0), bus)


async def test_a_goal_from_pending_to_succeeded(tracker: GoalTracker, bus: Bus) -> None:
    sub = bus.subscribe(EVENTS)
    a = tracker.new([Pose2D(1.0, 2.0)], "t1")
    b = tracker.new([Pose2D(3.0, 4.0)], "")
    assert (a.goal_id, b.goal_id) == (1, 2)
    tracker.queue(a)
    assert tracker.active is a and tracker.current is None and a.state is GoalState.PENDING
    assert tracker.activate() is a and tracker.activate() is None
    assert a.state is GoalState.ACTIVE and tracker.current is a and tracker.started_s == 100.0
    await tracker.clock.advance(2.5)  # type: ignore[attr-defined]
    tracker.finish(a, GoalState.SUCCEEDED, None, "goal reached")
    assert tracker.active is None and tracker.current is a  # done, still current
    (ev,) = sub.drain()
    assert ev.kind == "nav.goal_succeeded" and ev.stamp == 102.5
    assert ev.detail == {"note": "goal reached", "time_s": 2.5, "goal_id": 1, "tag": "t1",
                         "goal": [[1.0, 2.0]]}
    assert a.history == ["pending", "active", "succeeded: goal reached"]


def test_finish_with_an_error_and_another_kind(tracker: GoalTracker, bus: Bus) -> None:
    sub = bus.subscribe(EVENTS)
    h = tracker.new([Pose2D(1.0, 2.0)], "")
    tracker.finish(h, GoalState.ABORTED, NoPathError("cut off"), "recovery exhausted")
    tracker.finish(h, GoalState.PREEMPTED, None, "by the operator", kind="nav.goal_canceled")
    aborted, canceled = sub.drain()
    assert aborted.kind == "nav.goal_aborted" and "tag" not in aborted.detail
    assert aborted.detail["code"] == "no_path" and aborted.detail["message"] == "cut off"
    assert canceled.kind == "nav.goal_canceled" and "code" not in canceled.detail


def test_reject(tracker: GoalTracker, bus: Bus) -> None:
    sub = bus.subscribe(EVENTS)
    h = tracker.new([Pose2D(1.0, 2.0)], "")
    tracker.reject(h, NoPathError("nope"))
    assert h.state is GoalState.REJECTED and h.done and tracker.active is None
    (ev,) = sub.drain()
    assert ev.kind == "nav.goal_rejected" and ev.detail["code"] == "no_path"
    assert h.history == ["rejected: nope"]


def test_waypoints_then_the_goal(tracker: GoalTracker, bus: Bus) -> None:
    sub = bus.subscribe(EVENTS)
    h = tracker.new([Pose2D(0.0, 0.0), Pose2D(3.0, 0.0), Pose2D(3.0, 4.0)], "")
    assert tracker.advance(h) and h.current_index == 1
    assert tracker.advance(h) and h.current_index == 2
    assert not tracker.advance(h)
    assert (h.distance_remaining_m, h.eta_s) == (0.0, 0.0)
    assert [e.detail["index"] for e in sub.drain()] == [0, 1]


def test_feedback_adds_the_legs_to_come() -> None:
    h = GoalTracker(SimClock(), Bus()).new(
        [Pose2D(0.0, 0.0), Pose2D(3.0, 0.0), Pose2D(3.0, 4.0)], "")
    GoalTracker.feedback(h, 1.5, 0.3)
    assert h.distance_remaining_m == pytest.approx(1.5 + 3.0 + 4.0)
    assert h.eta_s == pytest.approx(8.5 / 0.3)
    h.current_index = 2
    GoalTracker.feedback(h, 1.0, 0.01)
    assert h.distance_remaining_m == 1.0 and h.eta_s == pytest.approx(1.0 / 0.05)


def test_queue_lets_the_current_goal_go_and_clear_forgets_both(tracker: GoalTracker) -> None:
    a, b = tracker.new([Pose2D()], ""), tracker.new([Pose2D()], "")
    tracker.queue(a)
    tracker.activate()
    tracker.queue(b)
    assert tracker.current is None and tracker.pending is b and tracker.active is b
    tracker.clear()
    assert tracker.active is None and tracker.pending is None


def test_an_event_without_a_goal(tracker: GoalTracker, bus: Bus) -> None:
    sub = bus.subscribe(EVENTS)
    tracker.event("nav.goal_rejected", None, code="invalid_goal")
    (ev,) = sub.drain()
    assert ev.detail == {"code": "invalid_goal"} and ev.stamp == 100.0
