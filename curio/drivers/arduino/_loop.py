"""Timed waits on the injected clock (only the ``Clock`` protocol)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from curio.core.clock import Clock

__all__ = ["wait_until"]


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
