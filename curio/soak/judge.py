"""Taking the campaign's faults one at a time and judging each (child side).

:class:`FaultRunner` is a part of the soak's rover. Every ``POLL_S`` of simulated time it
drains ``/health`` and ``/events``; when the next fault of the plan is due and its need holds
(the rover driving, a tour running) it injects it (:func:`curio.soak.faults.inject`) and
judges it:

* **detected in health** — a ``/health`` report of one of the fault's parts leaving ``ok``
  after the injection;
* **detected in the event log** — a record in the SQLite event log (queried every
  ``LOG_POLL_S``) written after the injection: a ``fault`` record of one of those parts or one
  of the fault's own kinds;
* **recovered** — once the fault condition has ended (the cable is back, the bus is quiet
  again, the disk has room), every one of those parts reports ``ok`` again (and the fault's own
  condition holds: localised where the rover really is, ...), within the kind's deadline; the
  time to recover is counted from the end of the condition (and the outage from the injection);
  while an operator's e-stop is engaged the drivers rightly stay disarmed, so that time is not
  counted against the fault (the deadline waits, ``held_by_operator_s`` says how long);
  a carried rover that is in its bounded relocalisation turn in place at the deadline (an
  operator's Resume starts one again) is judged when the turn is over (``waited_for_turn_s``);
* otherwise, **stopped safely and asked for help** — at the deadline the rover stands still
  and a help request is open (``help.requested``, or the tree's ``needs_help``); one that
  asked and is being driven by hand by an operator (teleop) counts as standing: the help came;
  anything else is **failed**.

Faults that restart the process (``kill9``, ``corrupt_file``) are announced to the orchestrator
(``kill_me``), which kills the rover; the next rover judges them from what it finds at start-up
(:meth:`FaultRunner.judge_restart`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from dataclasses import dataclass, field
from typing import Any

from curio.core.bus import Subscription
from curio.core.clock import wall_perf_counter
from curio.core.geometry import wrap_angle
from curio.core.messages import DriverHealth, Event, OperatorCommand, PoseWithCovariance
from curio.core.topics import (
    CMD_VEL_NAV,
    CMD_VEL_TELEOP,
    ESTOP,
    EVENTS,
    HEALTH,
    INITIAL_POSE,
    LOCALIZATION,
    OPERATOR,
    POSE,
    STATUS,
    TOUR,
)
from curio.eventlog.store import LogQuery
from curio.soak.faults import DEADLINES_S, Injection, Targets, inject
from curio.soak.link import Link
from curio.soak.plan import KIDNAP_KINDS, KINDS, PlannedFault

__all__ = ["FaultRun", "FaultRunner"]

log = logging.getLogger("curio.soak")

POLL_S = 0.25
LOG_POLL_S = 2.0
MOVING_MPS = 0.05
STILL_RADPS = 0.05  # and not turning faster than this: standing still (``still`` faults)
HEALTHY_WAIT_S = 60.0
NUDGE_S = 120.0  # simulated seconds a due fault waits for the rover to drive before a tour
KILL_WAIT_S = 30.0
LOCALISED_M = 0.3
LOCALISED_RAD = 0.15
HAND_FRESH_S = 1.0  # a teleop command this recent (s): an operator driving by hand
DRIVER_PARTS = ("lidar", "arduino", "imu")


@dataclass
class FaultRun:
    """One fault being judged (times are simulated seconds)."""

    fault: PlannedFault
    inj: Injection
    injected_s: float
    injected_wall_s: float
    cleared_s: float | None = None
    health_s: float | None = None
    log_s: float | None = None
    recovered_s: float | None = None
    help_s: float | None = None
    outcome: str = ""
    notes: list[str] = field(default_factory=list)
    clearing: asyncio.Task[None] | None = None
    good_since_s: float | None = None
    next_log_s: float = 0.0
    held_s: float = 0.0
    turn_wait_s: float = 0.0  # the deadline waited this long for a relocalisation turn
    cleared_wall_s: float | None = None  # wall_perf_counter() when the condition ended
    recovered_wall_s: float | None = None  # ... and when it was recovered

    def result(self) -> dict[str, Any]:
        """The judged fault for the report."""
        def rel(t: float | None) -> float | None:
            return None if t is None else round(t - self.injected_s, 3)

        cleared = self.cleared_s if self.cleared_s is not None else self.injected_s
        return {
            "id": self.fault.id, "kind": self.fault.kind, "params": self.fault.params,
            "injected_s": round(self.injected_s, 3), "injected_wall_s": self.injected_wall_s,
            "outcome": self.outcome, "detected_health_s": rel(self.health_s),
            "detected_log_s": rel(self.log_s), "cleared_s": rel(self.cleared_s),
            "recover_s": None if self.recovered_s is None else round(
                max(0.0, self.recovered_s - cleared - self.held_s), 3),
            "held_by_operator_s": round(self.held_s, 3),
            "waited_for_turn_s": round(self.turn_wait_s, 3),
            "recover_wall_s": None if self.recovered_wall_s is None or self.cleared_wall_s is None
            else round(self.recovered_wall_s - self.cleared_wall_s, 3),
            "outage_s": rel(self.recovered_s), "help_s": rel(self.help_s),
            "health_parts": list(self.inj.health), "note": self.inj.note, "notes": self.notes,
        }


class FaultRunner:
    """Injects the plan's faults in order and judges each (see the module docstring).

    Args:
        app: the running application.
        clock: its simulated clock.
        link: the line to the orchestrator.
        plan: the faults still to come, in time order.
        targets: what the injectors act on.
    """

    def __init__(self, app: Any, clock: Any, link: Link, plan: list[PlannedFault],
                 targets: Targets) -> None:
        self.app = app
        self.clock = clock
        self.link = link
        self.plan = list(plan)
        self.targets = targets
        self.current: FaultRun | None = None
        self.dying: PlannedFault | None = None
        self.dying_since_s = 0.0
        self.states: dict[str, str] = {}
        self.health_seen: dict[str, float] = {}
        self.help_open_s: float | None = None
        self.tree_lost = False  # between the tree's localization.lost and .found
        self.unhealthy_since_s: float | None = None
        self._waiting_since_s: float | None = None  # a due fault has waited for a drive since
        self._nudged_s = -math.inf
        self.judged = 0
        self._health: Subscription[DriverHealth] = app.bus.subscribe(HEALTH, maxsize=4096)
        self._events: Subscription[Event] = app.bus.subscribe(EVENTS)
        self.on_stall: Any = None

    # --- what the director asks ---------------------------------------------------------------

    @property
    def busy(self) -> bool:
        """A fault is being injected, judged or waited for death."""
        return self.current is not None or self.dying is not None

    def next_due_wall_s(self) -> float | None:
        """When the next fault is due (building clock). A due fault that waits for the rover to
        drive makes it now: the building's clock must not time-lapse past it while the rover
        stands parked (:meth:`_nudge` starts a tour for it after ``NUDGE_S``)."""
        if not self.plan:
            return None
        wall = self.clock.wall_time()
        if any(KINDS[f.kind].need != "any" and f.at_wall_s <= wall for f in self.plan):
            return float(wall)
        return self.plan[0].at_wall_s

    def describe(self) -> dict[str, Any]:
        """The runner's state for the heartbeat: the fault being judged, the next one and
        the parts that are not ``ok``."""
        nxt = self.plan[0] if self.plan else None
        return {"fault": self.current.fault.id if self.current is not None else None,
                "next_fault": None if nxt is None else [nxt.id, nxt.kind, round(
                    nxt.at_wall_s - self.clock.wall_time(), 1)],
                "not_ok": {k: v for k, v in self.states.items() if v != "ok"}}

    # --- the part -----------------------------------------------------------------------------

    async def run(self) -> None:
        """Poll until cancelled."""
        try:
            async for now in self.clock.every(POLL_S):
                self._drain(now)
                if self.current is not None:
                    self._judge(self.current, now)
                elif self.dying is not None:
                    if now - self.dying_since_s > KILL_WAIT_S:
                        self.link.send("fault", phase="result", id=self.dying.id,
                                       kind=self.dying.kind, outcome="failed",
                                       notes=["the orchestrator did not kill the rover"])
                        self.dying = None
                else:
                    self._maybe_inject(now)
        finally:
            self._health.close()
            self._events.close()
            if self.current is not None and self.current.clearing is not None:
                self.current.clearing.cancel()

    def _drain(self, now: float) -> None:
        for h in self._health.drain():
            self.states[h.name] = h.state
            self.health_seen[h.name] = h.stamp
            run = self.current
            if run is not None and h.name in run.inj.health and h.stamp >= run.injected_s \
                    and h.state in ("degraded", "error") and run.health_s is None:
                run.health_s = h.stamp
        for ev in self._events.drain():
            if ev.kind == "help.requested":
                self.help_open_s = ev.stamp
                if self.current is not None and self.current.help_s is None:
                    self.current.help_s = ev.stamp
            elif ev.kind == "help.resolved":
                self.help_open_s = None
            elif ev.kind in ("localization.lost", "localization.found"):
                self.tree_lost = ev.kind == "localization.lost"
        status = self.app.bus.latest(STATUS)
        if self.current is not None and self.current.help_s is None and status is not None \
                and status.state == "needs_help":
            self.current.help_s = now

    def _need_met(self, fault: PlannedFault) -> bool:
        need = KINDS[fault.kind].need
        if need == "any":
            return True
        v, w = self.app.world.truth_twist
        moving = bool(abs(v) > MOVING_MPS)
        if need == "moving":
            return moving
        if need == "still":
            return not moving and abs(w) < STILL_RADPS
        tour = self.app.bus.latest(TOUR)
        return moving and tour is not None and tour.tour_id is not None

    def _healthy(self) -> bool:
        return all(self.states.get(name, "ok") == "ok" for name in DRIVER_PARTS)

    def _next_ready(self) -> PlannedFault | None:
        """The first due fault whose need holds. A fault that waits for the rover to drive
        does not hold up the due faults behind it that need nothing (a campaign whose last
        tours were cut short used to leave all of them uninjected)."""
        wall = self.clock.wall_time()
        for fault in self.plan:
            if fault.at_wall_s > wall:
                return None
            if self._need_met(fault):
                return fault
        return None

    def _nudge(self, now: float) -> None:
        """A fault that needs the rover driving has waited ``NUDGE_S`` while it stood idle
        (the operators' random commands stopped the tours, or none is scheduled any more):
        start a tour for it, as the kiosk would (``source`` ``soak``), at most every
        ``NUDGE_S``."""
        wall = self.clock.wall_time()
        waiting = [f for f in self.plan if f.at_wall_s <= wall and not self._need_met(f)
                   and KINDS[f.kind].need != "still"]
        if not waiting or now - self._nudged_s < NUDGE_S:
            return
        if self._waiting_since_s is None:
            self._waiting_since_s = now
            return
        tour = self.app.bus.latest(TOUR)
        if now - self._waiting_since_s < NUDGE_S or (tour is not None and tour.tour_id):
            return
        self._nudged_s = now
        self.app.bus.publish(OPERATOR, OperatorCommand(
            now, "start_tour", source="soak", request_id=f"soak-nudge-{waiting[0].id}"))
        log.info("soak: fault %d (%s) waits for a tour: starting one", waiting[0].id,
                 waiting[0].kind)

    def _maybe_inject(self, now: float) -> None:
        fault = self._next_ready()
        if fault is None:
            self._nudge(now)
            return
        notes: list[str] = []
        if not self._healthy():
            if self.unhealthy_since_s is None:
                self.unhealthy_since_s = now
            if now - self.unhealthy_since_s < HEALTHY_WAIT_S:
                return
            bad = {k: v for k, v in self.states.items() if v != "ok"}
            notes.append(f"injected while parts were not ok: {bad}")
        self.unhealthy_since_s = None
        self._waiting_since_s = None
        self.plan.remove(fault)
        if KINDS[fault.kind].restart:
            self.dying, self.dying_since_s = fault, now
            self.link.send("kill_me", id=fault.id, kind=fault.kind, params=fault.params,
                           sim_s=now, wall_s=self.clock.wall_time())
            return
        self._start(fault, now, notes)

    def _start(self, fault: PlannedFault, now: float, notes: list[str]) -> None:
        try:
            inj = inject(fault, self.targets)
        except Exception as exc:  # a fault the soak could not inject is reported, not raised
            log.exception("soak: cannot inject %s", fault.kind)
            self.link.send("fault", phase="result", id=fault.id, kind=fault.kind,
                           outcome="not_injected", notes=[f"{type(exc).__name__}: {exc}"])
            return
        run = FaultRun(fault, inj, now, self.clock.wall_time(), notes=notes)
        if inj.clear is not None:
            run.clearing = asyncio.ensure_future(inj.clear())
        else:
            run.cleared_s = now
        if fault.kind == "loop_stall" and self.on_stall is not None:
            self.on_stall(now, now + float(fault.params.get("stall_s", 2.0)))
        self.current = run
        self.link.send("fault", phase="injected", id=fault.id, kind=fault.kind, sim_s=now,
                       wall_s=run.injected_wall_s, params=fault.params)

    # --- judging ------------------------------------------------------------------------------

    def _judge(self, run: FaultRun, now: float) -> None:
        if run.cleared_s is None and run.clearing is not None and run.clearing.done():
            run.cleared_s = now
            run.cleared_wall_s = wall_perf_counter()
            with contextlib.suppress(BaseException):
                run.clearing.result()
        if run.log_s is None and now >= run.next_log_s:
            run.next_log_s = now + LOG_POLL_S
            if self._logged(run):
                run.log_s = now
        if run.cleared_s is not None and run.recovered_s is None:
            if self._operator_estop():
                run.held_s += POLL_S  # an operator holds the rover: the deadline waits too
            elif self._recovered(run, now):
                run.recovered_s = now
                run.recovered_wall_s = wall_perf_counter()
        deadline = (run.cleared_s if run.cleared_s is not None else now) + run.inj.deadline_s \
            + run.held_s + run.turn_wait_s
        if run.cleared_s is not None and now >= deadline and run.recovered_s is None \
                and run.fault.kind in KIDNAP_KINDS and self._relocalise_turn(now) \
                and run.turn_wait_s < self._turn_s():
            # A lost rover in its bounded turn in place (started again by an operator's
            # Resume, say): the deadline waits for the turn to end, found or standing and
            # asking. Judged while it turned, it was "failed" for moving.
            if run.turn_wait_s == 0.0:
                run.notes.append("the deadline waited for a relocalisation turn")
            run.turn_wait_s += POLL_S
            deadline += POLL_S
        settled = run.recovered_s is not None and run.log_s is not None
        wall_wait = run.inj.wall_deadline_s is not None and run.cleared_wall_s is not None \
            and wall_perf_counter() - run.cleared_wall_s < run.inj.wall_deadline_s
        if settled or (run.cleared_s is not None and now >= deadline and not wall_wait):
            if run.recovered_s is not None:
                run.outcome = "recovered"
            elif self._stopped_safely(run, now):
                run.outcome = "stopped_safely"
                if run.fault.kind in KIDNAP_KINDS:
                    self._answer_lost_help(run, now)
            else:
                run.outcome = "failed"
            self.link.send("fault", phase="result", **run.result())
            self.judged += 1
            self.current = None

    def _turn_s(self) -> float:
        """How long the tree's relocalisation turn in place lasts at most (s)."""
        bt = self.app.cfg.bt
        return float(bt.relocalise_rotation_rad / bt.relocalise_speed_radps) + 2.0

    def _relocalise_turn(self, now: float) -> bool:
        """The tree is turning the rover in place to relocalise (its last drive command, of
        the last half second, is the turn's)."""
        cmd = self.app.bus.latest(CMD_VEL_NAV)
        return cmd is not None and cmd.source == "relocalise" and now - cmd.stamp <= 0.5 \
            and cmd.linear_mps == 0.0

    def _operator_estop(self) -> bool:
        """An operator's e-stop is engaged: the drivers rightly stay degraded (disarmed)
        until it is released, which is not the fault's doing."""
        estop = self.app.bus.latest(ESTOP)
        return estop is not None and estop.engaged and estop.source.startswith("web:")

    def _recovered(self, run: FaultRun, now: float) -> bool:
        since = run.cleared_s if run.cleared_s is not None else run.injected_s
        ok = all(self.states.get(name) == "ok" and self.health_seen.get(name, -1.0) >= since
                 for name in run.inj.must_recover)
        if ok and run.inj.recovered is not None:
            ok = run.inj.recovered()
        if ok and run.fault.kind in KIDNAP_KINDS:
            # the localiser's pose and state, and the tree back at work (found), not only the
            # localiser: a tree that stays lost keeps the rover out of service
            ok = self.localised() and not self.tree_lost
        if not ok:
            run.good_since_s = None
            return False
        if run.good_since_s is None:
            run.good_since_s = now
        return now - run.good_since_s >= 1.0

    def _answer_lost_help(self, run: FaultRun, now: float) -> None:
        """A carried rover that stopped and asked for help is answered as the help desk's
        person would: its pose set on the map where it stands (0.1 m, 0.05 rad), the
        dashboard's set-pose. Without it the rest of the soak ran with a rover out of service
        (a far-away answer is not trusted alone: docs/unattended.md)."""
        truth = self.app.world.truth_pose
        self.app.bus.publish(INITIAL_POSE, PoseWithCovariance.from_std(now, truth, 0.1, 0.05))
        run.notes.append("help answered: the pose set where the rover stands")
        log.info("soak: fault %d: a person answers the help request and sets the pose",
                 run.fault.id)

    def localised(self) -> bool:
        """Localisation ``ok`` and the pose within ``LOCALISED_M`` of the simulated rover."""
        bus = self.app.bus
        loc, est = bus.latest(LOCALIZATION), bus.latest(POSE)
        truth = self.app.world.truth_pose
        return (loc is not None and loc.state == "ok" and est is not None
                and est.pose.distance_to(truth) < LOCALISED_M
                and abs(wrap_angle(est.pose.yaw - truth.yaw)) < LOCALISED_RAD)

    def _driven_by_hand(self, now: float) -> bool:
        """An operator drives the rover by hand: a teleop command in the last
        ``HAND_FRESH_S`` (the safety stage follows one for ``teleop_timeout_s``, then ramps
        down), and the rover's own controller asks for no motion, so the motion is theirs."""
        bus = self.app.bus
        hand, own = bus.latest(CMD_VEL_TELEOP), bus.latest(CMD_VEL_NAV)
        if hand is None or now - hand.stamp > HAND_FRESH_S:
            return False
        return own is None or now - own.stamp > HAND_FRESH_S or (
            abs(own.linear_mps) < 1e-3 and abs(own.angular_radps) < 1e-3)

    def _stopped_safely(self, run: FaultRun, now: float) -> bool:
        v, w = self.app.world.truth_twist
        still = abs(v) < 0.01 and abs(w) < 0.01
        asked = run.help_s is not None or self.help_open_s is not None
        if not still and asked and self._driven_by_hand(now):
            # The help came: a person drives the rover by hand. The rover had stopped and
            # asked; the motion at the deadline is theirs (it was "failed" for moving).
            run.notes.append("driven by hand by an operator at the deadline")
            still = True
        if not still:
            run.notes.append("still moving at the deadline")
        if not asked:
            run.notes.append("no help request")
        return still and asked

    def _logged(self, run: FaultRun) -> bool:
        eventlog = self.app.eventlog
        if eventlog is None:
            return False
        kinds = ("fault", *run.inj.log_kinds)
        try:
            records = eventlog.query(LogQuery(since_wall_s=run.injected_wall_s - 1.0,
                                              kinds=kinds, limit=500))
        except Exception as exc:  # a full disk may refuse reads too: try again later
            run.notes.append(f"event log query failed: {exc}")
            return False
        for rec in records:
            if rec.kind in run.inj.log_kinds:
                return True
            if rec.kind == "fault" and (rec.source in run.inj.health
                                        or rec.detail.get("name") in run.inj.health):
                return True
        return False

    # --- after a restart ----------------------------------------------------------------------

    def judge_restart(self, fault: PlannedFault, killed_s: float, killed_wall_s: float,
                      health: tuple[str, ...], log_kinds: tuple[str, ...]) -> None:
        """Judge a restart fault from the new rover's start: detected when the parts in
        ``health`` and the records ``log_kinds`` report it; recovered when the drivers are ok
        and the rover is localised where it stands."""
        inj = Injection(health, log_kinds, None, DEADLINES_S.get(fault.kind, 120.0),
                        recovered=self._ready_after_restart, recovery_parts=DRIVER_PARTS)
        run = FaultRun(fault, inj, killed_s, killed_wall_s, cleared_s=killed_s)
        run.health_s = None
        self.current = run

    def _ready_after_restart(self) -> bool:
        return self._healthy() and all(n in self.states for n in DRIVER_PARTS) \
            and self.localised()
