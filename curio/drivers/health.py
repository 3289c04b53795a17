"""Helpers shared by the device drivers: timed waits and fixed-rate loops on the injected clock.

They use only the :class:`~curio.clock.Clock` protocol (``now``, ``sleep_until``), so a driver
works on the real clock on the rover and on the simulated clock in emulated mode.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

from curio.clock import Clock

__all__ = ["every", "wait_event"]


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


async def wait_event(clock: Clock, event: asyncio.Event, timeout_s: float) -> bool:
    """Wait for ``event`` at most ``timeout_s`` of clock time; return ``event.is_set()``."""
    if event.is_set():
        return True
    waiter = asyncio.ensure_future(event.wait())
    timer = asyncio.ensure_future(clock.sleep_until(clock.now() + max(0.0, timeout_s)))
    try:
        await asyncio.wait({waiter, timer}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in (waiter, timer):
            if not task.done():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
    return event.is_set()
