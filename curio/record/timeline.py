"""The replay's timeline: pause, play, speed and seek for ``curio replay --web``.

A replay re-runs the whole stack on a :class:`~curio.core.clock.SimClock` fed by the recorded
inputs, so time can only run forwards inside one run:

* **pause** stops driving the clock (every part waits on its timers; the dashboard's server,
  on real I/O, keeps answering and its pages stay connected);
* **seek forwards** runs the clock as fast as the CPU allows until the chosen time, then at the
  chosen speed again (or stays paused there) — everything between is computed, nothing
  skipped;
* **seek backwards** cannot rewind a computed run: the replay is *restarted* from that time
  (as ``--from T``: the localiser is seeded with the recorded pose there), on the same port
  and data directory (the same tokens), and the page reconnects by itself;
* at the **end** of the recording the dashboard stays up (paused at the end) until the
  operator presses Finish on the page, seeks back, or presses Ctrl-C; then the command prints
  its comparison report.

Positions are seconds from the start of the recording (``t0``, clock seconds). The timeline
is shared by the replay command (:mod:`curio.commands.replay`), which drives the clock through
:meth:`ReplayTimeline.drive`, and the dashboard (``/api/replay``), which calls the controls.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.clock import SimClock

__all__ = ["SPEEDS", "ReplayTimeline"]

# The speeds the page offers (None: as fast as the CPU allows).
SPEEDS: tuple[float | None, ...] = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, None)


@dataclass
class _Request:
    """What the operator asked for and the driver has not done yet."""

    seek_to_s: float | None = None
    restart_from_s: float | None = None
    finish: bool = False


class ReplayTimeline:
    """The controls of one replay (see the module docstring).

    Args:
        file_name: the recording's name (shown on the page).
        t0_s: clock time of the recording's start, seconds.
        end_s: the recording's length in seconds from ``t0_s`` (None: unknown).
        speed: × real time (None: as fast as possible).
        start_s: where this run starts, seconds from ``t0_s``.
    """

    def __init__(self, file_name: str, t0_s: float, end_s: float | None,
                 speed: float | None = 1.0, start_s: float = 0.0) -> None:
        self.file_name = file_name
        self.t0_s = t0_s
        self.end_s = end_s
        self.speed = speed
        self.start_s = start_s
        self.paused = False
        self.at_end = False
        self.restarts = 0
        self.port: int | None = None
        self.clock: SimClock | None = None
        self._req = _Request()
        self._changed = asyncio.Event()

    # --- what the page reads and asks ---------------------------------------------------------

    def position_s(self) -> float:
        """Where the replay is, seconds from the start of the recording."""
        return 0.0 if self.clock is None else max(0.0, self.clock.now() - self.t0_s)

    def status(self) -> dict[str, Any]:
        """JSON for the page: file, length, position, paused, speed, at the end."""
        return {"file": self.file_name, "end_s": self.end_s, "position_s":
                round(self.position_s(), 3), "paused": self.paused, "speed": self.speed,
                "at_end": self.at_end, "run_from_s": self.start_s, "restarts": self.restarts,
                "speeds": list(SPEEDS),
                "seeking_to_s": self._req.seek_to_s}

    def _poke(self) -> None:
        self._changed.set()

    def pause(self) -> None:
        """Hold the replay where it is."""
        self.paused = True
        self._poke()

    def play(self) -> None:
        """Go on (from the end: nothing to play; seek back first)."""
        self.paused = False
        self._poke()

    def set_speed(self, speed: float | None) -> None:
        """× real time, or None for as fast as possible.

        Raises:
            ValueError: not a positive finite number nor None.
        """
        if speed is not None and not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a number > 0 or 'max', got {speed!r}")
        self.speed = speed
        self._poke()

    def seek(self, t_s: float) -> str:
        """Go to ``t_s`` seconds from the start; return ``forward`` (computed up to there)
        or ``restart`` (the run starts again from there).

        Raises:
            ValueError: ``t_s`` is not within the recording.
        """
        end = self.end_s if self.end_s is not None else math.inf
        if not (math.isfinite(t_s) and 0.0 <= t_s <= end):
            shown = "its end" if self.end_s is None else f"{self.end_s:.1f} s"
            raise ValueError(f"seek to a time from 0 to {shown}, got {t_s!r}")
        if t_s >= self.position_s():
            self._req.seek_to_s = t_s
            how = "forward"
        else:
            self._req.restart_from_s = t_s
            how = "restart"
        self._poke()
        return how

    def finish(self) -> None:
        """End the replay now (the command then prints its report); also Ctrl-C."""
        self._req.finish = True
        self._poke()

    # --- what the replay command reads and calls ----------------------------------------------

    @property
    def restart_from_s(self) -> float | None:
        """Where the next run must start (a seek backwards), or None."""
        return self._req.restart_from_s

    @property
    def finished(self) -> bool:
        """Whether the operator ended the replay."""
        return self._req.finish

    def new_run(self, clock: SimClock) -> None:
        """A run starts on ``clock`` (the first one, or after a seek backwards)."""
        if self._req.restart_from_s is not None:
            self.start_s = self._req.restart_from_s
            self.restarts += 1
        self._req = _Request(finish=self._req.finish)
        self._changed = asyncio.Event()  # each run has its own event loop
        self.clock = clock
        self.at_end = False

    def _leaving(self) -> bool:
        return self._req.finish or self._req.restart_from_s is not None

    async def _wait(self) -> None:
        await self._changed.wait()
        self._changed.clear()

    async def drive(self, clock: SimClock, done: Callable[[], bool]) -> None:
        """Run ``clock`` until ``done()``, a restart or Finish, honouring pause, speed and
        seeks forwards."""
        while not done() and not self._leaving():
            self._changed.clear()
            target = self._req.seek_to_s
            if self.paused and target is None:
                await self._wait()
                continue
            if target is not None:
                self._req.seek_to_s = None
                clock.speed = None
                try:
                    await clock.run(until_s=self.t0_s + target,
                                    stop=lambda: done() or self._changed.is_set())
                finally:
                    clock.speed = self.speed
                continue
            clock.speed = self.speed
            await clock.run(stop=lambda: done() or self._changed.is_set())

    async def hold_at_end(self) -> None:
        """The recording is over: stay (paused at the end) until Finish or a seek back."""
        self.at_end = True
        self.paused = True
        while not self._leaving():
            self._req.seek_to_s = None  # nothing lies ahead
            await self._wait()
