"""The replay's timeline on a simulated clock: pause holds time, a seek forwards computes up to
the chosen time (and stays paused there if paused), a seek backwards asks for a restart, Finish
ends the run."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable

import pytest

from curio.core.clock import SimClock
from curio.record.timeline import ReplayTimeline


async def spin(until: Callable[[], bool] = lambda: False, polls: int = 200) -> bool:
    """Poll ``until()`` every millisecond (the clock's stepper settles between polls), at most
    ``polls`` times; True as soon as it holds. A False answer took ~``polls`` ms: enough for a
    clock at full speed to have run far if nothing held it."""
    for _ in range(polls):
        if until():
            return True
        await asyncio.sleep(0.001)  # noqa: TID251 - a poll interval, the loop left idle
    return until()


async def test_pause_seek_play_restart_and_finish() -> None:
    clock = SimClock(speed=None, start_s=10.0)
    timeline = ReplayTimeline("run.mcap", t0_s=10.0, end_s=100.0, speed=None)
    timeline.new_run(clock)

    async def ticker() -> None:  # the application's timers
        async for _ in clock.every(0.5):
            pass

    ticks = asyncio.create_task(ticker())
    timeline.pause()
    driver = asyncio.create_task(timeline.drive(clock, lambda: clock.now() >= 110.0))
    try:
        assert not await spin(lambda: clock.now() > 10.0), "paused, yet time moved"
        assert timeline.seek(30.0) == "forward"
        assert await spin(lambda: clock.now() == 40.0)
        assert not await spin(lambda: clock.now() > 40.0), "still paused after the seek"
        assert timeline.status()["position_s"] == 30.0 and timeline.paused
        timeline.play()
        assert await spin(lambda: clock.now() > 60.0)
        assert timeline.seek(5.0) == "restart"
        await asyncio.wait_for(driver, 5.0)  # the run ends: the command restarts from 5 s
        assert timeline.restart_from_s == 5.0
        timeline.new_run(SimClock(start_s=15.0))
        assert (timeline.start_s, timeline.restarts, timeline.restart_from_s) == (5.0, 1, None)
        with pytest.raises(ValueError, match=r"from 0 to 100\.0 s"):
            timeline.seek(120.0)
        timeline.finish()
        assert timeline.finished
    finally:
        for task in (ticks, driver):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


async def test_at_the_end_it_holds_until_finish() -> None:
    timeline = ReplayTimeline("run.mcap", t0_s=0.0, end_s=10.0)
    timeline.new_run(SimClock(start_s=10.0))
    holding = asyncio.create_task(timeline.hold_at_end())
    assert not await spin(holding.done)
    assert timeline.at_end and timeline.paused
    timeline.finish()
    await asyncio.wait_for(holding, 5.0)
