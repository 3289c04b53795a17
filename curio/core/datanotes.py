"""What happened to the data files at start-up, where an operator sees it.

The stores of tours, schedules and paths replace a file that cannot be used by its backup
(``<name>.bak``, a second copy of the last save), or — when the backup cannot be used either —
fall back to their defaults (the paths) or refuse to start (tours, schedules). :class:`DataNotes`
takes what they did (:meth:`DataNotes.restored`, :meth:`DataNotes.reset`) and, once the
application runs, publishes ``data.restored`` / ``data.reset`` on ``/events`` (the event log
keeps them) and ``/health`` name ``data``: ``degraded`` after a restore (nothing was lost),
``error`` after a reset (the operator's data is in the damaged file, kept beside it), for
``recent_s``; ``ok`` otherwise.
"""

from __future__ import annotations

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.messages import DriverHealth, Event
from curio.core.topics import EVENTS, HEALTH

__all__ = ["DataNotes"]


class DataNotes:
    """The data files' start-up notes (see the module docstring).

    Args:
        bus, clock: the application's.
        recent_s: how long ``/health`` shows a note, seconds.
    """

    def __init__(self, bus: Bus, clock: Clock, recent_s: float = 3600.0) -> None:
        self.bus = bus
        self.clock = clock
        self.recent_s = recent_s
        self.notes: list[tuple[str, str]] = []

    def restored(self, message: str | None) -> None:
        """A file was replaced by its backup (``message`` says which; None: nothing)."""
        if message:
            self.notes.append(("data.restored", message))

    def reset(self, message: str | None) -> None:
        """A file and its backup could not be used: defaults are used (None: nothing)."""
        if message:
            self.notes.append(("data.reset", message))

    def health(self, now: float, since: float) -> DriverHealth:
        """``/health`` ``data`` at ``now`` for notes made at ``since``."""
        if not self.notes or now - since >= self.recent_s:
            return DriverHealth(now, "data", "ok", "")
        lost = any(kind == "data.reset" for kind, _ in self.notes)
        text = "; ".join(message for _, message in self.notes)
        return DriverHealth(now, "data", "error" if lost else "degraded", text,
                            {"restored": float(sum(k == "data.restored" for k, _ in self.notes)),
                             "reset": float(sum(k == "data.reset" for k, _ in self.notes))})

    async def run(self) -> None:
        """Publish the notes, then ``/health`` every second until cancelled."""
        since = self.clock.now()
        for kind, message in self.notes:
            self.bus.publish(EVENTS, Event(since, kind, {"message": message}))
        async for now in self.clock.every(1.0, immediate=True):
            self.bus.publish(HEALTH, self.health(now, since))
