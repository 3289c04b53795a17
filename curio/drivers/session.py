"""The life of a device driver: connect → run a session → on a fault report it and back off →
reconnect, and the timed waits a session uses.

Every device driver (the Arduino base, the RPLidar, the BNO055) has the same shape: one
*session* opens the device, configures it and streams until something ends it; a
:class:`DeviceFault` (phrased for the person who has to fix it) ends a session and is reported
(``/health``, events, counters), then the next session starts after a back-off. A cancel (the
app shutting down) ends the loop. :class:`SessionLoop` is that loop; each driver gives it its
session and its hooks. Its ``/health`` side is :class:`~curio.drivers.health.HealthReporter`.

All waits use the injected :class:`~curio.core.clock.Clock` (``now``, ``sleep``,
``sleep_until``), so a driver runs on the real clock on the rover and on the simulated clock in
emulated mode.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from curio.core.clock import Clock
from curio.drivers.health import HealthReporter

__all__ = ["Backoff", "DeviceFault", "SessionLoop", "wait_event", "wait_until"]


class DeviceFault(Exception):
    """A session-ending problem, phrased for the person who has to fix it."""


@dataclass
class Backoff:
    """The waits between sessions: ``first_s``, doubled after each failed session up to
    ``max_s`` (``max_s == first_s``: always the same wait); :meth:`reset` starts over. Seconds."""

    first_s: float
    max_s: float
    _next_s: float = field(init=False)

    def __post_init__(self) -> None:
        self._next_s = self.first_s

    def reset(self) -> None:
        """The next wait is ``first_s`` again (the link worked)."""
        self._next_s = self.first_s

    def next(self) -> float:
        """The wait now, seconds; the one after is twice as long (at most ``max_s``)."""
        wait_s = self._next_s
        self._next_s = min(self.max_s, wait_s * 2.0)
        return wait_s


def _never() -> bool:
    return False


@dataclass
class SessionLoop:
    """Runs a driver's sessions until cancelled (or until ``stopped()``).

    Each round: ``session()``; when it returns the back-off starts over; when it raises one of
    ``faults``, ``on_fault(exc)`` reports it. Then (unless ``stopped()``) ``after()`` — release
    the device, say it is down — and the back-off's wait. Any other exception (a cancel: the
    app shuts down) runs ``on_abort()`` and propagates. With ``health`` and
    ``health_period_s``, ``/health`` is also published every ``health_period_s`` while the loop
    runs.

    Attributes:
        clock: the application clock (the waits).
        session: one session: open, configure, stream; raises a fault when it ends.
        on_fault: reports a fault (log, ``/health``, events, counters).
        backoff: the waits between sessions.
        faults: the exceptions that end a session and are retried.
        after: awaited after each session, before the wait (release the device...).
        on_abort: awaited when the loop ends by an exception (stop the device, release it).
        stopped: ends the loop; checked before each session and after each ends.
        health: publishes ``/health`` every ``health_period_s`` (None: the driver does it).
        health_period_s: seconds between those publications.
    """

    clock: Clock
    session: Callable[[], Awaitable[None]]
    on_fault: Callable[[Exception], None]
    backoff: Backoff
    faults: tuple[type[Exception], ...] = (DeviceFault,)
    after: Callable[[], Awaitable[None]] | None = None
    on_abort: Callable[[], Awaitable[None]] | None = None
    stopped: Callable[[], bool] = _never
    health: HealthReporter | None = None
    health_period_s: float = 1.0

    async def run(self) -> None:
        """Run sessions until cancelled or ``stopped()``."""
        reporter = None
        if self.health is not None:
            reporter = asyncio.ensure_future(self.health.run(self.health_period_s))
        try:
            while not self.stopped():
                if not await self._round():
                    break
                await self.clock.sleep(self.backoff.next())
        finally:
            if reporter is not None:
                reporter.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await reporter

    async def _round(self) -> bool:
        """One session and its reporting; False when the loop must end."""
        try:
            await self.session()
            self.backoff.reset()
        except self.faults as exc:
            if self.stopped():
                return False
            self.on_fault(exc)
        except BaseException:
            if self.on_abort is not None:
                await self.on_abort()
            raise
        if self.stopped():
            return False
        if self.after is not None:
            await self.after()
        return True


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
