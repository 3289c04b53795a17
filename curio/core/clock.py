"""Time for the whole application: the only module that reads time or sleeps (DESIGN rule 2).

Two clocks implement :class:`Clock`:

* :class:`RealClock` — monotonic wall time and ``asyncio.sleep``; used on the rover and by
  ``curio run``.
* :class:`SimClock` — virtual time. Sleepers wait on futures kept in a heap; :meth:`SimClock.run`
  lets every runnable task settle, then jumps straight to the next wake-up. It runs as fast as
  the CPU allows (``speed=None``) or at ``speed`` × real time, and for a given program and seed
  it is deterministic: timers fire in (time, registration order) order.

All times are seconds. ``now()`` is monotonic (the epoch is arbitrary, 0 for a fresh
``SimClock``); ``wall_time()`` is UNIX time for log and report stamps.

The clock also decides, once for the whole application, where heavy work runs
(:meth:`Clock.offload`): in a worker thread on the real clock, so the loop never blocks; inline
on a simulated clock, so a run never depends on wall-clock speed and stays deterministic.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import time
import types
from abc import ABC, abstractmethod
from collections.abc import AsyncIterator, Awaitable, Callable, Generator
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, runtime_checkable

T = TypeVar("T")

__all__ = [
    "Clock",
    "RateStats",
    "RealClock",
    "SimClock",
    "wall_perf_counter",
    "wall_sleep",
    "wall_time",
]


def wall_perf_counter() -> float:
    """Return a high-resolution wall-clock counter in seconds (for benchmarks and wall_time_s)."""
    return time.perf_counter()


def wall_time() -> float:
    """Return UNIX time in seconds (for report dates and log stamps, never for control)."""
    return time.time()


def wall_sleep(seconds: float) -> None:
    """Block the calling thread for ``seconds`` of wall time (device threads, never the loop)."""
    time.sleep(seconds)


def process_cpu_time() -> float:
    """Return CPU seconds used by this process (for CPU-fraction benchmarks)."""
    return time.process_time()


def thread_cpu_time() -> float:
    """Return CPU seconds used by the calling thread (a worker thread's own cost)."""
    return time.thread_time()


@dataclass
class RateStats:
    """Timing statistics of a fixed-rate loop (``Clock.every``).

    Attributes:
        ticks: iterations so far.
        overruns: iterations that started later than one whole period after their due time.
        max_lateness_s: worst lateness of an iteration's start against its due time, seconds.
    """

    ticks: int = 0
    overruns: int = 0
    max_lateness_s: float = 0.0


@runtime_checkable
class Clock(Protocol):
    """What every component gets instead of ``time`` and ``asyncio.sleep``."""

    def now(self) -> float:
        """Monotonic time in seconds."""
        ...

    def wall_time(self) -> float:
        """UNIX time in seconds (simulated clocks count from their configured epoch)."""
        ...

    async def sleep(self, dt_s: float) -> None:
        """Sleep ``dt_s`` seconds of this clock's time (at least one loop iteration)."""
        ...

    async def sleep_until(self, t_s: float) -> None:
        """Sleep until ``now() >= t_s``."""
        ...

    def every(
        self, period_s: float, stats: RateStats | None = None, *, phase_s: float = 0.0,
        immediate: bool = False,
    ) -> AsyncIterator[float]:
        """Yield the clock time once every ``period_s`` seconds, without drift."""
        ...

    async def wait_for(self, awaitable: Awaitable[T], timeout_s: float) -> T:
        """Await ``awaitable`` for at most ``timeout_s`` of clock time (TimeoutError after)."""
        ...

    async def wait_until(
        self, predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.05
    ) -> bool:
        """Poll ``predicate`` until it holds; False after ``timeout_s``."""
        ...

    def offload(self, fn: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        """Run ``fn(*args)`` off the loop when time is real (a future of its result)."""
        ...


@types.coroutine
def _yield_once() -> Generator[None, None, None]:
    """Give every other ready task one turn: what ``asyncio.sleep(0)`` does (the task yields
    once and is scheduled again), without its two coroutine frames."""
    yield


class _ClockMixin(ABC):
    """Helpers shared by both clocks, built on ``now``/``sleep_until``."""

    @abstractmethod
    def now(self) -> float:
        """Monotonic time in seconds."""

    @abstractmethod
    async def sleep_until(self, t_s: float) -> None:
        """Sleep until ``now() >= t_s``."""

    async def every(
        self, period_s: float, stats: RateStats | None = None, *, phase_s: float = 0.0,
        immediate: bool = False,
    ) -> AsyncIterator[float]:
        """Yield the clock time once every ``period_s`` seconds, without drift.

        The first iteration is due ``phase_s`` from now; like any sleep, waiting for it lets
        the other tasks run first. With ``immediate`` it runs at once instead, before any other
        task (as a loop that does its work, then sleeps), and the next ones follow every
        ``period_s`` from then. A late iteration is not repeated to catch up: the next due time
        skips ahead, and the miss is counted in ``stats.overruns``.
        """
        if period_s <= 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        due = self.now() + phase_s
        wait = not immediate
        while True:
            if wait:
                await self.sleep_until(due)
            wait = True
            now = self.now()
            if stats is not None:
                stats.ticks += 1
                stats.max_lateness_s = max(stats.max_lateness_s, now - due)
            yield now
            due += period_s
            behind = self.now() - due
            if behind > 0:
                # The iteration overran its period: skip the missed ticks, keep the phase.
                if stats is not None:
                    stats.overruns += 1
                due += period_s * (int(behind // period_s) + 1)

    async def wait_for(self, awaitable: Awaitable[T], timeout_s: float) -> T:
        """Await ``awaitable`` for at most ``timeout_s`` of clock time.

        Raises:
            TimeoutError: the awaitable did not finish in time (it is cancelled).
        """
        task = asyncio.ensure_future(awaitable)
        timer = asyncio.ensure_future(self.sleep_until(self.now() + timeout_s))
        try:
            await asyncio.wait({task, timer}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            timer.cancel()
        if task.done():
            return task.result()
        task.cancel()
        raise TimeoutError(f"timed out after {timeout_s:.3f} s")

    async def wait_until(
        self, predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.05
    ) -> bool:
        """Poll ``predicate`` every ``poll_s`` until it holds; return False after ``timeout_s``."""
        deadline = self.now() + timeout_s
        while not predicate():
            if self.now() >= deadline:
                return False
            await self.sleep_until(min(deadline, self.now() + poll_s))
        return True


class RealClock(_ClockMixin):
    """Monotonic wall time, for the rover and ``curio run``."""

    def offload(self, fn: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        """Run ``fn(*args)`` in a worker thread; the loop goes on meanwhile."""
        return asyncio.ensure_future(asyncio.to_thread(fn, *args))

    def now(self) -> float:
        """Monotonic time in seconds."""
        return time.monotonic()

    def wall_time(self) -> float:
        """UNIX time in seconds."""
        return time.time()

    async def sleep(self, dt_s: float) -> None:
        """Sleep ``dt_s`` seconds of wall time."""
        await asyncio.sleep(max(0.0, dt_s))

    async def sleep_until(self, t_s: float) -> None:
        """Sleep until the monotonic time reaches ``t_s``."""
        await asyncio.sleep(max(0.0, t_s - time.monotonic()))


class SimClock(_ClockMixin):
    """Virtual time for the simulator, tests and benchmarks.

    Args:
        speed: ``None`` runs as fast as the CPU allows; a number runs at that multiple of real
            time (1.0 = real time), sleeping on the wall clock between timer events.
        start_s: the initial value of ``now()``, seconds.
        epoch_wall_s: the UNIX time that ``wall_time()`` reports at ``now() == start_s``; fixed
            so reports are identical across runs.
        settle_polls: how many zero-length I/O polls the stepper grants after the loop looks
            idle before it moves time on (real pseudo-terminal I/O in emulated mode needs a few).
    """

    def __init__(
        self,
        speed: float | None = None,
        start_s: float = 0.0,
        epoch_wall_s: float = 1_700_000_000.0,
        settle_polls: int = 0,
    ) -> None:
        if speed is not None and speed <= 0:
            raise ValueError(f"speed must be > 0 or None, got {speed}")
        self.speed = speed
        self._now = start_s
        self._epoch_wall_s = epoch_wall_s - start_s
        self._timers: list[tuple[float, int, asyncio.Future[None]]] = []
        self._seq = itertools.count()
        self.settle_polls = settle_polls
        self.steps = 0

    def now(self) -> float:
        """Simulated monotonic time in seconds."""
        return self._now

    def wall_time(self) -> float:
        """Simulated UNIX time in seconds (a fixed epoch plus ``now()``)."""
        return self._epoch_wall_s + self._now

    async def sleep(self, dt_s: float) -> None:
        """Sleep ``dt_s`` simulated seconds."""
        await self.sleep_until(self._now + max(0.0, dt_s))

    async def sleep_until(self, t_s: float) -> None:
        """Sleep until simulated time reaches ``t_s`` (yields once even if it already has)."""
        if t_s <= self._now:
            await _yield_once()
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        heapq.heappush(self._timers, (t_s, next(self._seq), fut))
        await fut

    def offload(self, fn: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        """Run ``fn(*args)`` inline and return a finished future (its result or exception).

        Awaiting a finished future does not yield to the loop, so inline work keeps the
        order of events exactly as if it had been a plain call: runs stay deterministic.
        """
        fut: asyncio.Future[T] = asyncio.get_running_loop().create_future()
        try:
            fut.set_result(fn(*args))
        except Exception as exc:
            fut.set_exception(exc)
        return fut

    def jump_wall(self, dt_s: float) -> None:
        """Move the simulated wall clock (``wall_time()``) forward by ``dt_s`` seconds without
        moving ``now()``: a scenario's time-lapse over a stretch in which nothing happens (the
        control stack never reads wall time; schedules and logs do), or a test of a wall clock
        that jumps."""
        if not dt_s >= 0.0:
            raise ValueError(f"the wall clock only jumps forward, got {dt_s}")
        self._epoch_wall_s += dt_s

    def block(self, dt_s: float) -> None:
        """Move ``now()`` forward by ``dt_s`` seconds at once, running nothing: what an event
        loop blocked for ``dt_s`` looks like to the application (every timer due meanwhile
        fires late, ``every`` loops count an overrun). For fault injection (``curio soak``)."""
        if not dt_s >= 0.0:
            raise ValueError(f"time only moves forward, got {dt_s}")
        self._now += dt_s

    def pending_timers(self) -> int:
        """Number of live sleepers (cancelled ones are pruned lazily)."""
        return sum(1 for _, _, f in self._timers if not f.done())

    async def _settle(self) -> None:
        """Run every ready task until none is ready (each has blocked on a timer or I/O)."""
        loop = asyncio.get_running_loop()
        ready = getattr(loop, "_ready", None)
        idle_polls = 0
        for _ in range(100_000):
            await _yield_once()
            if ready is None:  # pragma: no cover - non-CPython loop: best effort
                idle_polls += 1
                if idle_polls > 20:
                    return
                continue
            if len(ready) == 0:
                idle_polls += 1
                if idle_polls > self.settle_polls:
                    return
            else:
                idle_polls = 0

    def _fire_due(self) -> int:
        """Resolve every timer due at the current time; return how many fired."""
        fired = 0
        while self._timers and self._timers[0][0] <= self._now:
            _, _, fut = heapq.heappop(self._timers)
            if not fut.done():
                fut.set_result(None)
                fired += 1
        return fired

    async def advance(self, dt_s: float) -> None:
        """Advance time by ``dt_s``, firing every timer on the way in order (for tests)."""
        await self.run(until_s=self._now + dt_s)

    async def run(
        self,
        until_s: float | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> None:
        """Drive simulated time until ``until_s``, until ``stop()`` is true, or for ever.

        Call it as a task beside the application (or await it from a test). When nothing is
        runnable and no timer is pending, it yields to real I/O for a millisecond.
        """
        wall_anchor = time.perf_counter()
        sim_anchor = self._now
        while True:
            await self._settle()
            if stop is not None and stop():
                return
            while self._timers and self._timers[0][2].done():
                heapq.heappop(self._timers)
            if not self._timers:
                if until_s is not None and self._now < until_s and self.speed is None:
                    self._now = until_s
                if until_s is not None and self._now >= until_s:
                    return
                await asyncio.sleep(0.001)
                continue
            t_next = self._timers[0][0]
            if until_s is not None and t_next > until_s:
                self._now = max(self._now, until_s)
                return
            if self.speed is not None:
                wall_due = wall_anchor + (t_next - sim_anchor) / self.speed
                delay = wall_due - time.perf_counter()
                if delay > 0:
                    await asyncio.sleep(delay)
            self._now = max(self._now, t_next)
            self.steps += 1
            self._fire_due()
