"""The replay source publishes inputs at their recorded times, before the application's own
timers due at the same instant; the comparison finds and measures divergences."""

from __future__ import annotations

import asyncio

import pytest

from curio.core.clock import SimClock
from curio.core.geometry import Pose2D
from curio.core.messages import NavGoal, OperatorCommand, Path, PoseWithCovariance, Twist
from curio.core.parts import Parts
from curio.core.topics import GOAL, OPERATOR, make_bus
from curio.record.compare import Tolerances, compare_paths, compare_poses, compare_twists
from curio.record.replay import ReplaySource, TimedInput


async def test_inputs_come_at_their_times_and_before_timers_due_then() -> None:
    bus, clock, parts = make_bus(), SimClock(), Parts()
    inputs = [TimedInput(1.0, 1, OPERATOR, OperatorCommand(1.0, "pause")),
              TimedInput(1.0, 2, OPERATOR, OperatorCommand(1.0, "resume")),
              TimedInput(2.5, 3, GOAL, NavGoal(2.5, "send", (Pose2D(1.0, 2.0, 0.0),)))]
    goals: list[NavGoal] = []
    source = ReplaySource(iter(inputs), on_goal=goals.append)
    source.register(bus, clock, parts)
    sub = bus.subscribe(OPERATOR)
    seen_at_tick: list[tuple[float, list[str]]] = []

    async def app_loop() -> None:  # an application timer ticking at 0.5 s, as the tree does
        async for t in clock.every(0.5):
            seen_at_tick.append((t, [c.action for c in sub.drain()]))

    assert parts.parts[0].run is not None
    tasks = [asyncio.create_task(app_loop()), asyncio.create_task(parts.parts[0].run())]
    await clock.run(until_s=3.0)
    for task in tasks:
        task.cancel()
    assert dict(seen_at_tick)[1.0] == ["pause", "resume"]  # at the 1.0 tick, in their order
    assert [g.poses[0] for g in goals] == [Pose2D(1.0, 2.0, 0.0)]
    assert source.done and source.published == {"/operator": 2, "/goal": 1}


def pose(x: float, yaw: float = 0.0) -> PoseWithCovariance:
    return PoseWithCovariance(0.0, Pose2D(x, 0.0, yaw))


def test_identical_series_compare_to_zero() -> None:
    rec = [(0.1 * i, pose(0.01 * i)) for i in range(50)]
    out = compare_poses(rec, list(rec), 0.0, Tolerances())
    assert out["max_error_m"] == 0.0 and out["over_tolerance"] == 0
    assert out["first_divergence_s"] is None


def test_a_drift_is_measured_where_and_when_it_starts() -> None:
    rec = [(0.1 * i, pose(0.01 * i)) for i in range(50)]
    rep = [(t, pose(p.pose.x + (0.002 if t >= 2.0 else 0.0))) for t, p in rec]
    out = compare_poses(rec, rep, 0.0, Tolerances(pose_tol_m=0.001))
    assert out["max_error_m"] == pytest.approx(0.002)
    assert out["first_divergence_s"] == pytest.approx(2.0) and out["over_tolerance"] == 30


def test_plans_and_commands() -> None:
    a = Path(1.0, (Pose2D(0, 0, 0), Pose2D(1, 0, 0)))
    b = Path(1.0, (Pose2D(0, 0.2, 0), Pose2D(1, 0.2, 0)))
    out = compare_paths([(1.0, a), (2.0, a)], [(1.0, a), (2.0, b)], 0.0, Tolerances())
    assert out["max_hausdorff_m"] == pytest.approx(0.2) and out["first_divergence_s"] == 2.0
    empty = compare_paths([(1.0, a)], [(1.0, Path(1.0, ()))], 0.0, Tolerances())
    assert empty["max_hausdorff_m"] is None and empty["over_tolerance"] == 1  # inf: one side
    tw = compare_twists([(1.0, Twist(1.0, 0.2, 0.1))], [(0.5, Twist(0.5, 0.25, 0.1))], 0.0,
                        Tolerances())
    assert tw["max_linear_diff_mps"] == pytest.approx(0.05) and tw["over_tolerance"] == 1
