"""The tour journal: a tour cut short by a crash or a stop of Curio is reported at the next
start, never resumed by itself.

While a tour runs, ``<data_dir>/tours.running.json`` says which (id, name, who started it, the
request id, when, how many stops it has and how many were reached); it is written atomically
at ``tour.started`` and at every ``tour.stop``, and removed at ``tour.finished`` /
``tour.stopped``. When Curio starts and finds it, the tour was interrupted (``kill -9``, a
crash, a power cut, or a stop of Curio during the tour): :class:`TourJournal` publishes
``tour.interrupted`` with what the file says and a sentence for the operator, and removes the
file. The rover does not pick the tour up again: it stays where it is until a schedule or an
operator says otherwise.

File writes go through ``clock.offload`` (a worker thread on the real clock). A write that fails
(a full disk) is tried again every ``RETRY_S`` until it succeeds: once, the soak's disk was
full at ``tour.started`` and the journal gave up, so the ``kill -9`` that came later in the
tour left nothing to report (seed 2, 2026-12-03).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from pathlib import Path
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.fileio import atomic_write_json, read_json
from curio.core.messages import Event
from curio.core.topics import EVENTS

__all__ = ["TourJournal"]

log = logging.getLogger("curio.tours.journal")

FIELDS = ("tour_id", "tour", "source", "request_id", "stops")
RETRY_S = 2.0  # a failed write is tried again this often (clock seconds)


class TourJournal:
    """Keeps ``tours.running.json`` while a tour runs; reports an interrupted one at start.

    Args:
        path: the journal file.
        bus, clock: the application's.
    """

    def __init__(self, path: Path, bus: Bus, clock: Clock) -> None:
        self.path = path
        self.bus = bus
        self.clock = clock
        self.interrupted: dict[str, Any] | None = self._read()
        self.current: dict[str, Any] | None = None
        self._events = bus.subscribe(EVENTS)
        self.unsaved = False  # the file does not say what ``current`` says (a write failed)
        self._writing = asyncio.Lock()  # one write at a time, each of the state at its call

    def _read(self) -> dict[str, Any] | None:
        try:
            data = read_json(self.path)
        except (OSError, ValueError) as exc:
            log.warning("the tour journal %s cannot be read (%s): reporting an unknown tour",
                        self.path, exc)
            return {"tour": "", "error": str(exc)}
        if data is None:
            return None
        return data if isinstance(data, dict) else {"tour": ""}

    def report(self) -> None:
        """Publish ``tour.interrupted`` for the tour found at start (if any)."""
        rec = self.interrupted
        if rec is None:
            return
        name = str(rec.get("tour") or "a tour")
        reached, stops = rec.get("stops_reached", 0), rec.get("stops")
        where = f" after {reached} of {stops} stops" if stops else ""
        message = (f"The tour '{name}' was interrupted{where}: Curio stopped during it "
                   "(a crash, a power cut or a restart) and did not resume it; the rover stays "
                   "where it is until a schedule or an operator starts something.")
        self.bus.publish(EVENTS, Event(self.clock.now(), "tour.interrupted", {
            **{k: rec.get(k) for k in FIELDS}, "stops_reached": reached,
            "started_wall_s": rec.get("started_wall_s"), "message": message}))
        self.interrupted = None

    async def _write(self) -> None:
        async with self._writing:
            try:
                if self.current is None:
                    await self.clock.offload(self.path.unlink, True)  # missing_ok
                else:
                    await self.clock.offload(atomic_write_json, self.path, dict(self.current))
            except OSError as exc:  # a full disk: the tour goes on, the write is tried again
                if not self.unsaved:
                    log.warning("cannot write the tour journal %s (trying again every %g s): "
                                "%s", self.path, RETRY_S, exc)
                self.unsaved = True
                return
            if self.unsaved:
                log.info("the tour journal %s is written again", self.path)
            self.unsaved = False

    async def _retry(self) -> None:
        async for _ in self.clock.every(RETRY_S):
            if self.unsaved:
                await self._write()

    async def on_event(self, ev: Event) -> None:
        """Follow one event."""
        if ev.kind == "tour.started":
            self.current = {**{k: ev.detail.get(k) for k in FIELDS}, "stops_reached": 0,
                            "started_wall_s": round(self.clock.wall_time(), 3)}
        elif ev.kind == "tour.stop" and self.current is not None:
            self.current["stops_reached"] = int(self.current.get("stops_reached", 0)) + 1
        elif ev.kind in ("tour.finished", "tour.stopped") and self.current is not None:
            self.current = None
        else:
            return
        await self._write()

    async def run(self) -> None:
        """Report an interrupted tour, then follow the tours until cancelled."""
        retry = asyncio.create_task(self._retry(), name="tour-journal-retry")
        try:
            if self.interrupted is not None:
                self.report()
                self.current = None
                await self._write()
            async for ev in self._events:
                await self.on_event(ev)
        finally:
            retry.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await retry

    async def close(self) -> None:
        """Stop following (the file stays while a tour runs: it was interrupted)."""
        self._events.close()
