"""The scheduler: starts scheduled tours at their local time when the rover is ready.

A part that runs on the injected clock (``clock.every(tours.check_period_s)``) and reads the
building's time from ``clock.wall_time()`` — on a simulated clock a whole day passes in
minutes. Every check it takes the starts that fell due since the last check
(:meth:`ScheduleStore.occurrences`) and tries each in time order:

* Ready (:func:`readiness`: no e-stop, the tree idle/arrived/docked and no tour running,
  battery at or above ``tours.min_battery_v``, localised) → it asks for the tour like the
  dashboard does (``start_tour`` with ``source="scheduler"``) and waits for the tree's answer:
  accepted → ``tour.scheduled_start``; refused → ``tour.skipped`` with the tree's reason.
* Not ready → ``tour.delayed`` once with the reason (the operator sees it at once), and it keeps
  trying for ``tours.start_window_s``; then ``tour.skipped`` with the last reason.

Starts that were due longer ago than the window when first seen (Curio was not running, or the
wall clock jumped forward) are skipped at once with that reason. Nothing before the
scheduler's own start is replayed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import ToursConfig
from curio.core.messages import Event
from curio.core.topics import BATTERY, ESTOP, EVENTS, LOCALIZATION, STATUS, TOUR

from .model import TourError
from .schedule import Occurrence, ScheduleStore

__all__ = ["READY_STATES", "Readiness", "Scheduler", "readiness"]

log = logging.getLogger("curio.tours.scheduler")

# Status states (curio/bt) in which the rover may start a tour.
READY_STATES = frozenset({"idle", "arrived", "docked", "charging"})
ANSWER_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class Readiness:
    """Whether a scheduled tour may start now, and if not, why (a sentence)."""

    ready: bool
    reason: str = ""


def readiness(bus: Bus, min_battery_v: float, require_localised: bool = True) -> Readiness:
    """Read ``/estop``, ``/status``, ``/tour``, ``/battery`` and ``/localization``."""
    estop = bus.latest(ESTOP)
    if estop is not None and estop.engaged:
        return Readiness(False, "the e-stop is engaged")
    status = bus.latest(STATUS)
    if status is None:
        return Readiness(False, "the behaviour tree has not reported its state yet")
    tour = bus.latest(TOUR)
    if tour is not None and tour.tour_id is not None:
        return Readiness(False, f"the tour '{tour.name}' is still running")
    if status.state not in READY_STATES:
        return Readiness(False, f"the rover is busy ({status.text})")
    battery = bus.latest(BATTERY)
    if battery is None:
        return Readiness(False, "there is no battery reading yet")
    if battery.voltage_v < min_battery_v:
        return Readiness(False, f"the battery is at {battery.voltage_v:.2f} V, below the "
                                f"{min_battery_v:.2f} V a tour needs")
    if require_localised:
        loc = bus.latest(LOCALIZATION)
        if loc is None:
            return Readiness(False, "the rover is not localised yet")
        if loc.state in ("lost", "uncertain"):
            return Readiness(False, f"the rover is not sure where it is (localisation "
                                    f"{loc.state})")
    return Readiness(True)


@dataclass
class _Due:
    """A scheduled start being tried."""

    occ: Occurrence
    deadline_wall_s: float
    reason: str = ""
    delayed: bool = False
    request_id: str = ""
    asked_at_s: float = 0.0


@dataclass
class SchedulerStats:
    """Counters since start."""

    started: int = 0
    skipped: int = 0
    delayed: int = 0
    skip_reasons: list[str] = field(default_factory=list)


class Scheduler:
    """Starts scheduled tours (see the module docstring).

    Args:
        schedules: the schedule store.
        start: ``start(tour_id, source, request_id)`` asks for a tour; raises
            :class:`TourError` when it cannot even be asked for (the tour was deleted, has no
            stops...).
        tour_name: a tour's name for events ("" if unknown).
        bus, clock: the application's.
        cfg: ``[tours]``.
        require_localised: False when localisation is off (nothing to wait for).
    """

    def __init__(self, schedules: ScheduleStore, start: Callable[[int, str, str], Any],
                 tour_name: Callable[[int], str], bus: Bus, clock: Clock, cfg: ToursConfig,
                 require_localised: bool = True) -> None:
        self.schedules = schedules
        self.start = start
        self.tour_name = tour_name
        self.bus = bus
        self.clock = clock
        self.cfg = cfg
        self.require_localised = require_localised
        self.pending: list[_Due] = []
        self.stats = SchedulerStats()
        self.last_check_wall_s: float | None = None
        self._events = bus.subscribe(EVENTS)
        self._count = 0

    async def run(self) -> None:
        """Check every ``tours.check_period_s`` until cancelled."""
        async for _ in self.clock.every(self.cfg.check_period_s):
            self.check()

    def close(self) -> None:
        """Stop listening for the tree's answers."""
        self._events.close()

    def _event(self, kind: str, due: _Due, **detail: Any) -> None:
        occ = due.occ
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, {
            "schedule_id": occ.schedule_id, "tour_id": occ.tour_id,
            "tour": self.tour_name(occ.tour_id), "due": occ.local.isoformat(timespec="minutes"),
            **detail}))

    def check(self) -> None:
        """One check: take new due starts, read answers, start or skip."""
        now_wall = self.clock.wall_time()
        if self.last_check_wall_s is None:
            self.last_check_wall_s = now_wall
        if now_wall > self.last_check_wall_s:
            for occ in self.schedules.occurrences(self.last_check_wall_s, now_wall):
                due = _Due(occ, occ.wall_s + self.cfg.start_window_s)
                if now_wall > due.deadline_wall_s:
                    self._skip(due, "it was missed: Curio was not running or its clock jumped "
                                    "forward at that time")
                else:
                    self.pending.append(due)
            self.last_check_wall_s = now_wall
        self._read_answers()
        for due in list(self.pending):
            if due.request_id:
                if self.clock.now() - due.asked_at_s > ANSWER_TIMEOUT_S:
                    self._skip(due, "the behaviour tree did not answer the start request")
                continue
            self._try(due, now_wall)

    def _try(self, due: _Due, now_wall: float) -> None:
        if any(d.request_id for d in self.pending):
            state = Readiness(False, "another tour is being started")
        else:
            state = readiness(self.bus, self.cfg.min_battery_v, self.require_localised)
        if state.ready:
            self._count += 1
            due.request_id = f"schedule-{due.occ.schedule_id}-{int(due.occ.wall_s)}"
            due.asked_at_s = self.clock.now()
            try:
                self.start(due.occ.tour_id, "scheduler", due.request_id)
            except TourError as exc:
                self._skip(due, str(exc))
            return
        due.reason = state.reason
        if now_wall > due.deadline_wall_s:
            self._skip(due, f"the rover was not ready within {self.cfg.start_window_s:g} s: "
                            f"{state.reason}")
        elif not due.delayed:
            due.delayed = True
            self.stats.delayed += 1
            self._event("tour.delayed", due, reason=state.reason,
                        window_s=self.cfg.start_window_s,
                        message=f"The {due.occ.local:%H:%M} tour waits: {state.reason}.")

    def _read_answers(self) -> None:
        asked = {d.request_id: d for d in self.pending if d.request_id}
        for ev in self._events.drain():
            if not asked or ev.kind not in ("bt.command_accepted", "bt.command_rejected"):
                continue
            due = asked.pop(str(ev.detail.get("request_id", "")), None)
            if due is None:
                continue
            if ev.kind == "bt.command_accepted":
                self.pending.remove(due)
                self.stats.started += 1
                late = self.clock.wall_time() - due.occ.wall_s
                self._event("tour.scheduled_start", due, request_id=due.request_id,
                            late_s=round(max(0.0, late), 1))
            else:
                self._skip(due, f"the rover refused it: {ev.detail.get('message', '')}")

    def _skip(self, due: _Due, reason: str) -> None:
        if due in self.pending:
            self.pending.remove(due)
        self.stats.skipped += 1
        self.stats.skip_reasons.append(reason)
        log.warning("scheduled tour %s at %s skipped: %s", due.occ.tour_id, due.occ.label,
                    reason)
        self._event("tour.skipped", due, reason=reason,
                    message=f"The {due.occ.local:%H:%M} tour was skipped: {reason}.")
