"""Watching the event loop itself: a blocked loop is a fault like an unplugged cable.

Every part of Curio runs on one asyncio loop; a part that blocks it (a slow call that should
have been offloaded, a busy wait) stops everything else, the safety stage included, until it
returns — only the firmware's own watchdog keeps the wheels safe meanwhile. :class:`LoopWatch`
ticks every ``period_s`` of the injected clock and measures how late each tick came: a tick
later than ``stall_s`` means the loop was blocked for about that long. It then publishes
``loop.stalled`` (``blocked_s``, seconds) on ``/events`` and reports ``/health`` name ``loop``
``degraded`` until ``clear_s`` have passed without another stall; counters ``stalls``,
``worst_blocked_s`` and ``last_blocked_s``.

On the real clock lateness is wall time; on a simulated clock a loop blocked for real does not
move simulated time (nothing is late), while ``SimClock.block`` — how ``curio soak`` injects
a stall — does.
"""

from __future__ import annotations

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.messages import DriverHealth, Event
from curio.core.topics import EVENTS, HEALTH

__all__ = ["LoopWatch"]


class LoopWatch:
    """Notices a blocked event loop (see the module docstring).

    Args:
        bus, clock: the application's.
        period_s: the tick, seconds.
        stall_s: a tick this much later than due is a stall, seconds.
        clear_s: ``degraded`` lasts this long after the last stall, seconds.
        health_s: how often ``/health`` is published, seconds.
    """

    def __init__(self, bus: Bus, clock: Clock, period_s: float = 0.1, stall_s: float = 0.5,
                 clear_s: float = 5.0, health_s: float = 1.0) -> None:
        self.bus = bus
        self.clock = clock
        self.period_s = period_s
        self.stall_s = stall_s
        self.clear_s = clear_s
        self.health_s = health_s
        self.stalls = 0
        self.worst_blocked_s = 0.0
        self.last_blocked_s = 0.0
        self.last_stall_at: float | None = None

    def tick(self, now: float, last: float) -> None:
        """One tick at ``now``; the previous one was at ``last`` (clock seconds)."""
        blocked = now - last - self.period_s
        if blocked < self.stall_s:
            return
        self.stalls += 1
        self.last_blocked_s = blocked
        self.worst_blocked_s = max(self.worst_blocked_s, blocked)
        self.last_stall_at = now
        self.bus.publish(EVENTS, Event(now, "loop.stalled", {
            "blocked_s": round(blocked, 3),
            "message": f"The event loop was blocked for {blocked:.1f} s: nothing else ran "
                       "meanwhile (a part did slow work on the loop)."}))
        self.publish(now)

    def health(self, now: float) -> DriverHealth:
        """``ok``, or ``degraded`` within ``clear_s`` of a stall."""
        recent = self.last_stall_at is not None and now - self.last_stall_at < self.clear_s
        message = (f"the event loop was blocked for {self.last_blocked_s:.1f} s "
                   f"{now - self.last_stall_at:.0f} s ago" if recent and
                   self.last_stall_at is not None else "")
        return DriverHealth(now, "loop", "degraded" if recent else "ok", message, {
            "stalls": float(self.stalls), "worst_blocked_s": round(self.worst_blocked_s, 3),
            "last_blocked_s": round(self.last_blocked_s, 3)})

    def publish(self, now: float) -> None:
        """Publish ``/health`` now."""
        self.bus.publish(HEALTH, self.health(now))

    async def run(self) -> None:
        """Tick until cancelled."""
        last = self.clock.now()
        next_health = last
        async for now in self.clock.every(self.period_s):
            self.tick(now, last)
            last = now
            if now >= next_health:
                next_health = now + self.health_s
                self.publish(now)
