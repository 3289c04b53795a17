"""Pinned: the navigator's timing thresholds at their shipped values.

Written before the navigation refactor so that it cannot move them by accident. The navigator
runs with the real costmap, planner and controller against the fake rover of the navigator
tests, on a simulated clock and a real bus. The pinned keys keep their defaults; the times
asserted are absolute, so changing a default, or removing its check, breaks a test:

* ``nav.controller.lost_timeout_s`` = 10 s: localisation lost (or no pose at all) holds the goal
  for 10 s, then aborts it;
* ``nav.planner.blocked_confirm_s`` = 0.5 s: a blocked plan is replaced 0.5 s after the
  blockage is first seen (the cycle runs at 16 Hz here, so the times are exact);
* ``nav.recovery.goal_progress_timeout_s`` = 20 s: no closer to the goal for 20 s is stuck;
* ``nav.recovery.max_rounds`` = 2: the ladder is climbed twice before an unreachable goal is
  given up.
"""

from __future__ import annotations

import math

import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event, LocalizationStatus
from curio.core.topics import LOCALIZATION
from curio.estimation.maps import OccupancyGrid
from curio.nav.api import GoalState, LocalizationLostError, NoPathError, NoProgressError
from tests.unit.test_navigator import Harness, cell, room


def with_updates(cfg: Config, **sections: dict[str, object]) -> Config:
    """A deep copy of ``cfg`` with ``nav.<section>.<key>`` overrides (for keys not pinned)."""
    out = cfg.model_copy(deep=True)
    for section, updates in sections.items():
        for key, value in updates.items():
            setattr(getattr(out.nav, section), key, value)
    return out


def stamps(events: list[Event], kind: str) -> list[float]:
    return [e.stamp for e in events if e.kind == kind]


# --- lost_timeout_s -------------------------------------------------------------------------


async def test_lost_localisation_aborts_the_goal_after_10_s_not_before(cfg: Config) -> None:
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.5, 0.0, math.nan))
        await h.clock.advance(2.0)
        assert handle.state is GoalState.ACTIVE
        h.bus.publish(LOCALIZATION, LocalizationStatus(h.clock.now(), "lost"))
        t_lost = h.clock.now()
        await h.clock.advance(9.9)
        assert handle.state is GoalState.ACTIVE  # held, not given up
        assert await h.until(lambda: handle.done, 0.4)
        assert handle.state.value == "aborted"  # (mypy keeps ACTIVE narrowed from above)
        assert isinstance(handle.error, LocalizationLostError)
        assert "for 10 s" in str(handle.error)
        (t_abort,) = stamps(h.events.drain(), "nav.goal_aborted")
        assert 10.0 < t_abort - t_lost <= 10.2 + 1e-9


async def test_no_pose_aborts_the_goal_10_s_after_the_pose_goes_stale(cfg: Config) -> None:
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.5, 0.0, math.nan))
        await h.clock.advance(2.0)
        assert handle.state is GoalState.ACTIVE
        h.tasks[0].cancel()  # the rover stops publishing /pose (localisation is not running)
        t_last_pose = h.clock.now()
        # A pose older than 1 s is no pose; the goal is held for 10 s after that.
        await h.clock.advance(1.0 + 9.9)
        assert handle.state is GoalState.ACTIVE
        assert await h.until(lambda: handle.done, 0.5)
        assert isinstance(handle.error, LocalizationLostError)
        assert "no pose in map for 10 s" in str(handle.error)
        (t_abort,) = stamps(h.events.drain(), "nav.goal_aborted")
        assert 11.0 < t_abort - t_last_pose <= 11.3


# --- blocked_confirm_s ----------------------------------------------------------------------


async def test_a_blocked_plan_is_replaced_0_5_s_after_it_is_first_seen(cfg: Config) -> None:
    # 16 Hz: every cycle time is an exact binary fraction (not a pinned key; the default is
    # 10 Hz, whose 0.1 s steps cannot resolve 0.5 s from 0.4 s or 0.6 s exactly).
    cfg = with_updates(cfg, controller={"rate_hz": 16.0}, planner={"replan_rate_hz": 0.0})
    period = 1.0 / 16.0
    grid = room()
    async with Harness(cfg, grid, Pose2D(-3.0, 0.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(3.0, 0.0, math.nan))
        await h.clock.run(until_s=1.0 + period / 2)  # between two cycles
        plans = h.nav.plan_count
        h.events.drain()
        blocked = grid.data.copy()
        r, c = cell(grid, -1.0, -0.5)  # about 2 m ahead, across the straight line
        blocked[r:r + 20, c:c + 10] = 100
        h.costmap.set_static_map(OccupancyGrid(blocked, grid.resolution_m, grid.origin))
        first_seen = 1.0 + period  # the next cycle sees it
        await h.clock.run(until_s=first_seen + 0.5 - period / 2)
        assert h.nav.plan_count == plans  # 0.4375 s after it was first seen: kept
        await h.clock.run(until_s=first_seen + 0.5 + period / 2)
        assert h.nav.plan_count == plans + 1
        (t_replan,) = stamps(h.events.drain(), "nav.path_blocked")
        assert t_replan - first_seen == pytest.approx(0.5)
        assert handle.state is GoalState.ACTIVE


# --- goal_progress_timeout_s ----------------------------------------------------------------


async def test_no_progress_towards_the_goal_for_20_s_is_stuck(cfg: Config) -> None:
    # Only the goal-progress check may fire: the controller's own (10 s) is switched off.
    cfg = with_updates(cfg, controller={"progress_timeout_s": 1000.0},
                       recovery={"ladder": ["wait"]})
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        h.rover.frozen = True  # the wheels turn, the rover gets no closer
        handle = h.nav.send_goal(Pose2D(2.0, 0.0, math.nan))
        await h.clock.advance(0.3)
        events = h.events.drain()
        (t_accepted,) = stamps(events, "nav.goal_accepted")
        await h.clock.run(until_s=t_accepted + 19.9)
        assert handle.recoveries == 0 and handle.state is GoalState.ACTIVE
        assert stamps(h.events.drain(), "nav.keep_out") == []
        await h.clock.run(until_s=t_accepted + 20.5)
        assert handle.recoveries == 1
        assert any("no_progress" in line for line in handle.history)
        (t_stuck,) = stamps(h.events.drain(), "nav.keep_out")
        assert 20.0 < t_stuck - t_accepted <= 20.4


async def test_the_goal_progress_message_names_20_s(cfg: Config) -> None:
    cfg = with_updates(cfg, controller={"progress_timeout_s": 1000.0},
                       recovery={"ladder": ["wait"], "max_rounds": 1, "wait_s": 1.0})
    async with Harness(cfg, room(), Pose2D(-2.0, 0.0, 0.0)) as h:
        h.rover.frozen = True
        handle = h.nav.send_goal(Pose2D(2.0, 0.0, math.nan))
        assert await h.until(lambda: handle.done, 60.0)
        assert isinstance(handle.error, NoProgressError)
        assert "no progress towards the goal for 20 s" in str(handle.error)


# --- max_rounds -----------------------------------------------------------------------------


async def test_the_ladder_is_climbed_twice_before_giving_up(cfg: Config) -> None:
    grid = room()
    # A closed box around (2, 2): the goal inside is free but cut off.
    r, c = cell(grid, 1.0, 1.0)
    grid.data[r:r + 41, c] = grid.data[r:r + 41, c + 40] = 100
    grid.data[r, c:c + 41] = grid.data[r + 40, c:c + 41] = 100
    async with Harness(cfg, grid, Pose2D(-2.0, -2.0, 0.0)) as h:
        handle = h.nav.send_goal(Pose2D(2.0, 2.0, math.nan))
        assert await h.until(lambda: handle.done, 300.0)
        assert handle.state is GoalState.ABORTED
        assert isinstance(handle.error, NoPathError) and "after recovery" in str(handle.error)
        steps = [rec.name for rec in h.recovery.history]  # type: ignore[union-attr]
        ladder = ["clear_costmap", "step_back", "rotate", "wait"]
        assert list(cfg.nav.recovery.ladder) == ladder  # the shipped ladder
        assert steps == ladder * 2
        assert handle.recoveries == 8
