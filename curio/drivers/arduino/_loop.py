"""Fixed-rate loops and timed waits on the injected clock (only the ``Clock`` protocol)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable

from curio.clock import Clock

__all__ = ["every", "wait_until"]


async def every(clock: Clock, period_s: float) -> AsyncIterator[float]:
    """Yield the clock time every ``period_s`` seconds without drift (late ticks skip ahead)."""
    if period_s <= 0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    due = clock.now()
    while True:
        await clock.sleep_until(due)
        now = clock.now()
        yield now
        due += period_s
        if due < now:
            due = now + period_s


async def wait_until(clock: Clock, predicate: Callable[[], bool], timeout_s: float,
                     event: asyncio.Event, poll_s: float = 0.05) -> bool:
    """Wait until ``predicate()`` holds, re-checking whenever ``event`` is set (and at least
    every ``poll_s``); return False after ``timeout_s`` of clock time."""
    deadline = clock.now() + timeout_s
    while not predicate():
        now = clock.now()
        if now >= deadline:
            return False
        event.clear()
        waiter = asyncio.ensure_future(event.wait())
        timer = asyncio.ensure_future(clock.sleep_until(min(deadline, now + poll_s)))
        try:
            await asyncio.wait({waiter, timer}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            waiter.cancel()
            timer.cancel()
    return True
