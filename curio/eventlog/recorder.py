"""The recorder: what happens on the bus, into the event log, with wall-clock time.

A part polling its subscriptions every ``POLL_S`` of clock time:

* ``/events`` — every event (tour started/finished/stopped/skipped, stop reached ``tour.stop``,
  help requested/resolved with ``waited_s``, collisions, navigation, dock events when they
  come), kind unchanged, except ``eventlog.ignore_kinds`` and the answers to operator
  commands: the command journal (``curio/eventlog/commands.py``) writes the commands, as
  ``operator.<action>`` with their source, and their answers, ahead of telling anyone;
* ``/estop`` — ``estop.engaged`` / ``estop.released`` when the state changes;
* ``/health`` — ``fault`` when a part goes to ``error`` or ``degraded``, ``fault.cleared``
  when it is ``ok`` again (the event log's own trouble too: its records are written once
  writes work again);
* ``/odom`` — distance driven and time moving, summed and logged as ``motion`` records
  (``distance_m``, ``moving_s`` over ``period_s``) every ``eventlog.motion_summary_s`` while
  they change, and at shutdown.

A message's wall time is ``clock.wall_time()`` less its age on the clock. The recorder also
publishes its own health (``eventlog``) with the writer's counters.
"""

from __future__ import annotations

import math
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import EventLogConfig
from curio.core.messages import DriverHealth
from curio.core.topics import ESTOP, EVENTS, HEALTH, ODOM

from .commands import ANSWER_KINDS
from .store import EventLog

__all__ = ["EventRecorder"]

POLL_S = 0.25
HEALTH_PERIOD_S = 5.0
MOVING_MPS = 0.02
TURNING_RADPS = 0.05
FAULT_STATES = ("error", "degraded")


class EventRecorder:
    """Feeds the event log from the bus (see the module docstring).

    Args:
        log: the event log.
        bus, clock: the application's.
        cfg: ``[eventlog]``.
    """

    def __init__(self, log: EventLog, bus: Bus, clock: Clock, cfg: EventLogConfig) -> None:
        self.log = log
        self.bus = bus
        self.clock = clock
        self.cfg = cfg
        self._events = bus.subscribe(EVENTS)
        self._estop = bus.subscribe(ESTOP)
        self._health = bus.subscribe(HEALTH, maxsize=512)
        self._odom = bus.subscribe(ODOM, maxsize=256)
        self._estop_engaged: bool | None = None
        self._states: dict[str, str] = {}
        self._last_odom: tuple[float, float, float] | None = None
        self._distance_m = 0.0
        self._moving_s = 0.0
        self._summary_from_s = clock.now()
        self._health_due_s = clock.now()
        self.recorded = 0

    def wall(self, stamp: float) -> float:
        """The wall time of a message stamped ``stamp`` on the clock."""
        return self.clock.wall_time() - (self.clock.now() - stamp)

    def _append(self, stamp: float, kind: str, detail: dict[str, Any], source: str = "") -> None:
        self.log.append(kind, detail, wall_s=self.wall(stamp), source=source)
        self.recorded += 1

    def _ignored(self, kind: str) -> bool:
        return any(kind == k or (k.endswith(".") and kind.startswith(k))
                   for k in self.cfg.ignore_kinds)

    async def run(self) -> None:
        """Poll until cancelled."""
        async for _ in self.clock.every(POLL_S):
            self.poll()

    def poll(self) -> None:
        """Move everything received to the log."""
        for ev in self._events.drain():
            if ev.kind not in ANSWER_KINDS and not self._ignored(ev.kind):
                source = ev.detail.get("source", "")
                self._append(ev.stamp, ev.kind, dict(ev.detail),
                             source if isinstance(source, str) else "")
        for es in self._estop.drain():
            if es.engaged != self._estop_engaged:
                if es.engaged or self._estop_engaged is not None:
                    self._append(es.stamp, "estop.engaged" if es.engaged else "estop.released",
                                 {"reason": es.reason}, es.source)
                self._estop_engaged = es.engaged
        for health in self._health.drain():
            self._health_change(health)
        for odom in self._odom.drain():
            self._motion(odom.stamp, odom.pose.x, odom.pose.y, odom.linear_mps,
                         odom.angular_radps)
        now = self.clock.now()
        if now - self._summary_from_s >= self.cfg.motion_summary_s:
            self.summarise()
        if now >= self._health_due_s:
            self._health_due_s = now + HEALTH_PERIOD_S
            self._publish_health()

    def _health_change(self, health: DriverHealth) -> None:
        before = self._states.get(health.name)
        self._states[health.name] = health.state
        if health.state == before:
            return
        if health.state in FAULT_STATES:
            self._append(health.stamp, "fault", {"name": health.name, "state": health.state,
                                                 "message": health.message}, health.name)
        elif health.state == "ok" and before in FAULT_STATES:
            self._append(health.stamp, "fault.cleared", {"name": health.name,
                                                         "was": before}, health.name)

    def _motion(self, stamp: float, x: float, y: float, linear: float, angular: float) -> None:
        last = self._last_odom
        self._last_odom = (stamp, x, y)
        if last is None or stamp <= last[0]:
            return
        self._distance_m += math.hypot(x - last[1], y - last[2])
        if abs(linear) > MOVING_MPS or abs(angular) > TURNING_RADPS:
            self._moving_s += stamp - last[0]

    def summarise(self) -> None:
        """Log the distance and time moving since the last summary (if any)."""
        now = self.clock.now()
        if self._distance_m > 1e-3 or self._moving_s > 0.0:
            self._append(now, "motion", {"distance_m": round(self._distance_m, 3),
                                         "moving_s": round(self._moving_s, 2),
                                         "period_s": round(now - self._summary_from_s, 2)})
        self._distance_m = 0.0
        self._moving_s = 0.0
        self._summary_from_s = now

    def _publish_health(self) -> None:
        stats = self.log.stats
        state = "degraded" if stats.failing else "ok"
        message = (f"writes failing ({stats.last_error}): {stats.retrying} records kept and "
                   "retried every few seconds; free some disk space" if stats.failing else "")
        self.bus.publish(HEALTH, DriverHealth(
            self.clock.now(), "eventlog", state, message,
            {"written": float(stats.written), "queued": float(self.log.pending()),
             "retrying": float(stats.retrying), "lost": float(stats.lost),
             "errors": float(stats.errors), "pruned": float(stats.pruned)}))

    def close(self) -> None:
        """Record what is left, stop listening."""
        self.poll()
        self.summarise()
        for sub in (self._events, self._estop, self._health, self._odom):
            sub.close()
