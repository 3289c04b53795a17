"""A blocked event loop is detected and reported (found by ``curio soak``: a part blocking the
loop for 2 s left no trace in ``/health`` or the event log)."""

from __future__ import annotations

import asyncio

import pytest

from curio.core.clock import SimClock
from curio.core.loopwatch import LoopWatch
from curio.core.topics import EVENTS, HEALTH, make_bus


async def test_a_blocked_loop_is_an_event_and_degraded_health_until_it_clears() -> None:
    clock = SimClock()
    bus = make_bus()
    events, health = bus.subscribe(EVENTS), bus.subscribe(HEALTH, maxsize=100)
    watch = LoopWatch(bus, clock, clear_s=5.0)
    task = asyncio.create_task(watch.run())
    await clock.advance(3.0)
    assert not events.drain() and all(h.state == "ok" for h in health.drain())

    async def block() -> None:
        await clock.sleep(0.05)
        clock.block(2.0)  # what a part that blocks the loop for 2 s looks like

    blocker = asyncio.create_task(block())
    await clock.advance(1.0)
    stalled = [e for e in events.drain() if e.kind == "loop.stalled"]
    assert len(stalled) == 1 and stalled[0].detail["blocked_s"] == pytest.approx(1.95, abs=0.15)
    states = [h.state for h in health.drain()]
    assert "degraded" in states
    await clock.advance(6.0)
    assert [h.state for h in health.drain()][-1] == "ok"
    assert watch.stalls == 1 and blocker.done()
    task.cancel()


async def test_ordinary_ticks_are_not_stalls() -> None:
    clock = SimClock()
    bus = make_bus()
    events = bus.subscribe(EVENTS)
    task = asyncio.create_task(LoopWatch(bus, clock).run())
    await clock.advance(60.0)
    assert events.drain() == []
    task.cancel()
