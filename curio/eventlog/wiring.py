"""Event-log wiring: the SQLite log in ``<data_dir>`` and the recorder part.

Built first in the composition root, so its subscriptions see every message from the start.
"""

from __future__ import annotations

from dataclasses import dataclass

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.parts import Part, Parts

from .recorder import EventRecorder
from .store import EventLog

__all__ = ["EventLogging", "build_eventlog", "open_log"]


@dataclass(frozen=True)
class EventLogging:
    """The event log and its recorder."""

    log: EventLog
    recorder: EventRecorder


def open_log(cfg: Config, *, readonly: bool = False) -> EventLog:
    """The configured event log (``<data_dir>/<eventlog.file>``)."""
    ev = cfg.eventlog
    return EventLog(cfg.data_path(ev.file), max_age_days=ev.max_age_days,
                    max_rows=ev.max_rows, batch_rows=ev.batch_rows, readonly=readonly)


def build_eventlog(cfg: Config, bus: Bus, clock: Clock, parts: Parts) -> EventLogging | None:
    """Open the log and register the recorder (None when ``eventlog.enabled`` is off)."""
    if not cfg.eventlog.enabled:
        return None
    log = open_log(cfg)
    recorder = EventRecorder(log, bus, clock, cfg.eventlog)

    async def close() -> None:
        recorder.close()
        await clock.offload(log.close)

    parts.add(Part("eventlog", run=recorder.run, close=close))
    return EventLogging(log, recorder)
