"""The recovery ladder: rungs, rounds, giving up, starting afresh on real progress."""

from __future__ import annotations

import asyncio

from curio.core.clock import SimClock
from curio.core.config import RecoveryConfig
from curio.nav.api import NoPathError, StartBlockedError
from curio.nav.costs import CostGrid
from curio.nav.navigator.ladder import GiveUp, RecoveryLadder
from curio.nav.recovery import RecoveryOutcome


class FakeActions:
    """Records the steps run; an action ends when its event is set."""

    def __init__(self, with_costmap: bool = True) -> None:
        self.costmap: CostGrid | None = object() if with_costmap else None  # type: ignore[assignment]
        self.ran: list[str] = []
        self.cleared = 0
        self.release = asyncio.Event()

    async def run(self, step: str) -> RecoveryOutcome:
        self.ran.append(step)
        await self.release.wait()
        return RecoveryOutcome(step, True)

    def clear_costmap(self) -> RecoveryOutcome:
        self.cleared += 1
        return RecoveryOutcome("clear_costmap", True)


CLOCK = SimClock()
LADDER = RecoveryConfig(ladder=["clear_costmap", "step_back", "wait"], max_rounds=2)


async def test_climbs_rung_by_rung_then_round_again_then_gives_up() -> None:
    actions = FakeActions()
    ladder = RecoveryLadder(LADDER, actions)
    actions.release.set()
    steps = []
    for _ in range(6):
        step = ladder.climb(NoPathError("no path"), 5.0)
        assert isinstance(step, str)
        steps.append(step)
        await CLOCK.sleep(0.0)  # one turn of the loop
        assert ladder.collect()
    assert steps == LADDER.ladder * 2
    assert actions.ran == steps
    out = ladder.climb(NoPathError("no path"), 5.0)
    assert isinstance(out, GiveUp) and out.note == "recovery exhausted"
    assert isinstance(out.error, NoPathError)
    assert str(out.error) == "no path (after recovery: clear_costmap, step_back, wait)"


async def test_max_rounds_1_gives_up_after_one_round() -> None:
    ladder = RecoveryLadder(LADDER.model_copy(update={"max_rounds": 1}), FakeActions())
    for _ in range(3):
        assert isinstance(ladder.climb(NoPathError("x"), 5.0), str)
        ladder.cancel()
    assert isinstance(ladder.climb(NoPathError("x"), 5.0), GiveUp)


def test_without_actions_or_rungs_it_gives_up_at_once() -> None:
    for ladder in (RecoveryLadder(LADDER, None),
                   RecoveryLadder(LADDER.model_copy(update={"ladder": []}), FakeActions())):
        out = ladder.climb(NoPathError("no path"), 5.0)
        assert isinstance(out, GiveUp) and out.note == "stuck, no recovery configured"
        assert str(out.error) == "no path"


async def test_busy_until_the_action_ends() -> None:
    actions = FakeActions()
    ladder = RecoveryLadder(LADDER, actions)
    assert not ladder.busy and not ladder.collect()
    ladder.climb(NoPathError("x"), 5.0)
    await CLOCK.sleep(0.0)  # one turn of the loop
    assert ladder.busy and not ladder.collect()
    actions.release.set()
    await CLOCK.sleep(0.0)  # one turn of the loop
    assert ladder.collect() and not ladder.busy


async def test_cancel_stops_the_action() -> None:
    ladder = RecoveryLadder(LADDER, FakeActions())
    ladder.climb(NoPathError("x"), 5.0)
    ladder.cancel()
    assert not ladder.busy


async def test_real_progress_starts_afresh_driving_back_does_not() -> None:
    ladder = RecoveryLadder(LADDER, FakeActions())
    assert ladder.climb(NoPathError("x"), 5.0) == "clear_costmap"
    ladder.cancel()
    assert ladder.climb(NoPathError("x"), 5.0) == "step_back"  # stuck at 5 m from the goal
    ladder.cancel()
    ladder.note_progress(4.1)  # back to where it got stuck, not 1 m beyond
    assert ladder.climb(NoPathError("x"), 5.0) == "wait"
    ladder.cancel()
    ladder.note_progress(3.9)  # 1 m closer than where the ladder was last climbed
    assert ladder.climb(NoPathError("x"), 3.9) == "clear_costmap"
    ladder.cancel()


async def test_reset_for_a_new_goal() -> None:
    ladder = RecoveryLadder(LADDER.model_copy(update={"max_rounds": 1}), FakeActions())
    for _ in range(3):
        ladder.climb(NoPathError("x"), 5.0)
        ladder.cancel()
    ladder.reset()
    assert ladder.climb(StartBlockedError("x"), 5.0) == "clear_costmap"
    ladder.cancel()


def test_clear_under_rover_needs_a_costmap() -> None:
    actions = FakeActions()
    RecoveryLadder(LADDER, actions).clear_under_rover()
    assert actions.cleared == 1
    none = FakeActions(with_costmap=False)
    RecoveryLadder(LADDER, none).clear_under_rover()
    RecoveryLadder(LADDER, None).clear_under_rover()
    assert none.cleared == 0
