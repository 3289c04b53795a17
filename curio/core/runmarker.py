"""Knowing, at start-up, that the last run did not stop cleanly.

While Curio runs, ``<data_dir>/running.json`` holds its process id, when it started and its
last sign of life (refreshed every ``ALIVE_S``); a clean stop removes it. When Curio starts and
the file is there, the last run ended without stopping (``kill -9``, a crash, a power cut):
:class:`RunMarker` publishes ``system.unclean_restart`` (when that run started, when it was
last alive, and a sentence) and reports ``/health`` name ``process`` ``degraded`` for
``recent_s``, so the health panel and the event log show it; after that, or after a clean
start, ``ok`` with the start time.

File writes go through ``clock.offload`` (a worker thread on the real clock); a full disk only
makes the marker stale (logged once), it never stops the rover.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.fileio import atomic_write_json, read_json
from curio.core.messages import DriverHealth, Event
from curio.core.topics import EVENTS, HEALTH

__all__ = ["RunMarker"]

log = logging.getLogger("curio.runmarker")

ALIVE_S = 30.0
HEALTH_S = 1.0


class RunMarker:
    """The run marker (see the module docstring).

    Args:
        path: the marker file.
        bus, clock: the application's.
        recent_s: ``/health`` stays ``degraded`` this long after an unclean restart, seconds.
    """

    def __init__(self, path: Path, bus: Bus, clock: Clock, recent_s: float = 600.0) -> None:
        self.path = path
        self.bus = bus
        self.clock = clock
        self.recent_s = recent_s
        self.previous: dict[str, Any] | None = self._read()
        self.started_wall_s = clock.wall_time()
        self.started_s = clock.now()
        self._write_failed = False

    def _read(self) -> dict[str, Any] | None:
        try:
            data = read_json(self.path)
        except (OSError, ValueError) as exc:
            return {"error": f"the marker could not be read: {exc}"}
        return None if data is None else data if isinstance(data, dict) else {}

    @property
    def unclean(self) -> bool:
        """The last run did not stop cleanly."""
        return self.previous is not None

    def health(self, now: float) -> DriverHealth:
        """``degraded`` within ``recent_s`` of an unclean restart, else ``ok``."""
        if self.unclean and now - self.started_s < self.recent_s:
            return DriverHealth(now, "process", "degraded", self._sentence(), {"unclean": 1.0})
        return DriverHealth(now, "process", "ok", "running", {"unclean": float(self.unclean)})

    def _sentence(self) -> str:
        alive = (self.previous or {}).get("alive_wall_s")
        ago = f" (last sign of life {self.started_wall_s - float(alive):.0f} s before this " \
              "start)" if isinstance(alive, int | float) else ""
        return (f"restarted after an unclean stop (crash, kill or power cut){ago}: check the "
                "event log for what was running")

    async def _write(self) -> None:
        record = {"pid": os.getpid(), "started_wall_s": round(self.started_wall_s, 3),
                  "alive_wall_s": round(self.clock.wall_time(), 3)}
        try:
            await self.clock.offload(atomic_write_json, self.path, record)
            self._write_failed = False
        except OSError as exc:
            if not self._write_failed:
                log.warning("cannot write the run marker %s: %s", self.path, exc)
            self._write_failed = True

    async def run(self) -> None:
        """Report an unclean restart, then keep the marker fresh and ``/health`` every
        ``HEALTH_S`` until cancelled."""
        if self.unclean:
            prev = self.previous or {}
            self.bus.publish(EVENTS, Event(self.clock.now(), "system.unclean_restart", {
                "previous_started_wall_s": prev.get("started_wall_s"),
                "previous_alive_wall_s": prev.get("alive_wall_s"),
                "previous_pid": prev.get("pid"), "message": self._sentence()}))
        await self._write()
        next_alive = self.clock.now() + ALIVE_S
        async for now in self.clock.every(HEALTH_S, immediate=True):
            self.bus.publish(HEALTH, self.health(now))
            if now >= next_alive:
                next_alive = now + ALIVE_S
                await self._write()

    async def close(self) -> None:
        """A clean stop: remove the marker."""
        try:
            await self.clock.offload(self.path.unlink, True)  # missing_ok
        except OSError as exc:
            log.warning("cannot remove the run marker %s: %s", self.path, exc)
