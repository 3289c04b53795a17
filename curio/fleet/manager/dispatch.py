"""Tours as jobs: pick the best rover, send the tour, watch it, and re-dispatch when needed.

A *job* is one run of a tour that somebody asked for (an operator on the fleet page, a kiosk,
a schedule). Its life:

``queued`` → ``sent`` (a signed ``start_tour`` with the tour's definition and the request id
``job<N>-<attempt>`` went to one rover) → ``running`` (the rover's ``tour.started`` with that
request id came) → ``done`` (``tour.finished``). A queued job that no rover can take within
``start_window_s`` is ``dropped`` with the reason; one that failed ``max_attempts`` times too.

**The best rover** (:meth:`Dispatcher.candidates`): online, *ready* by its own rule (no e-stop,
idle/arrived/docked/charging, no tour, battery at or above the rover's minimum, localised —
``docs/tours.md``), at or above ``min_battery_v`` and, when the rover reports its power
model's state of charge, at or above ``min_soc``; not busy with another job, not one that
already failed this job; then the nearest by driving distance on the shared map to the tour's
first stop (within ``NEAR_EQUAL_M`` counts as equally near), then the fuller battery (state of
charge first — rovers that report one before those that do not — then voltage), then the
name.

**Re-dispatch** (the job goes back to the queue, the rover is excluded for it):

* the rover refused (``fleet.command_refused`` reply, ``bt.command_rejected``) or did not
  start the tour within ``ack_timeout_s``;
* it has been offline for ``redispatch_after_s`` (it keeps driving safely on its own; when it
  comes back still running that tour it is told to stop and go home, because another rover
  has the visitors now);
* its battery fell below ``low_battery_v``, or its state of charge below ``low_soc``, during
  the tour (it is told to stop and to dock — ``go_home`` on a rover without a dock);
* its tour stopped (``tour.stopped`` not asked for by the manager) or has been ``failed`` for
  ``failed_tour_s`` (stopped and sent home).

The dispatcher is pure logic on the injected wall time: it acts through ``send(rover, cmd)``
and reports through ``note(kind, detail)`` (``dispatch.*`` events).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from curio.core.config import FleetManagerConfig
from curio.fleet.manager.roster import Roster, RoverState

__all__ = ["Dispatcher", "Job"]

RESEND_S = 3.0
# Rovers whose driving distances differ by less than this are equally near: the fuller
# battery goes (it also spreads the work over the fleet).
NEAR_EQUAL_M = 3.0


@dataclass
class Job:
    """One requested run of a tour (see the module docstring)."""

    id: int
    tour_id: int
    tour_name: str
    source: str
    created_wall_s: float
    deadline_wall_s: float
    state: str = "queued"
    rover: str | None = None
    request_id: str = ""
    attempts: int = 0
    excluded: set[str] = field(default_factory=set)
    sent_wall_s: float = 0.0
    last_send_wall_s: float = 0.0
    started_wall_s: float | None = None
    ended_wall_s: float | None = None
    failed_since: float | None = None
    stopping: set[str] = field(default_factory=set)
    reason: str = ""
    history: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """For the API and reports."""
        return {"id": self.id, "tour_id": self.tour_id, "tour": self.tour_name,
                "source": self.source, "state": self.state, "rover": self.rover,
                "attempts": self.attempts, "reason": self.reason,
                "created_wall_s": round(self.created_wall_s, 3),
                "started_wall_s": self.started_wall_s, "ended_wall_s": self.ended_wall_s,
                "history": self.history}


class Dispatcher:
    """Jobs and their rovers (see the module docstring).

    Args:
        cfg: ``fleet.manager``.
        roster: the rovers.
        distance: driving distance (m) from a rover's pose to a tour's first stop.
        tour_def: a tour's definition (JSON) by id; raises KeyError when it is gone.
        send: sends a command dict to a rover (the manager signs it).
        note: records a ``dispatch.*`` event.
    """

    def __init__(self, cfg: FleetManagerConfig, roster: Roster,
                 distance: Callable[[RoverState, int], float],
                 tour_def: Callable[[int], dict[str, Any]],
                 send: Callable[[str, dict[str, Any]], None],
                 note: Callable[[str, dict[str, Any]], None]) -> None:
        self.cfg = cfg
        self.roster = roster
        self.distance = distance
        self.tour_def = tour_def
        self.send = send
        self.note = note
        self.jobs: list[Job] = []
        self._ids = itertools.count(1)
        self.redispatches = 0
        self.orphans: dict[str, int] = {}

    # --- requests ---------------------------------------------------------------------------
    def request(self, tour_id: int, tour_name: str, source: str, now: float) -> Job:
        """Queue a run of tour ``tour_id``."""
        job = Job(next(self._ids), tour_id, tour_name, source, now,
                  now + self.cfg.start_window_s)
        self.jobs.append(job)
        self._note("dispatch.queued", job)
        return job

    def active(self) -> list[Job]:
        """Jobs not done or dropped."""
        return [j for j in self.jobs if j.state in ("queued", "sent", "running")]

    def _note(self, kind: str, job: Job, **extra: Any) -> None:
        job.history.append(kind.removeprefix("dispatch.") + (f": {extra['reason']}"
                                                             if "reason" in extra else ""))
        self.note(kind, {"job": job.id, "tour": job.tour_name, "rover": job.rover,
                         "source": job.source, **extra})

    # --- what rovers say --------------------------------------------------------------------
    def _job_of(self, rover: str, request_id: str) -> Job | None:
        if not request_id:
            return None
        return next((j for j in self.jobs if j.request_id == request_id and j.rover == rover
                     and j.state in ("sent", "running")), None)

    def on_event(self, rover: str, ev: dict[str, Any], now: float) -> None:
        """A rover's event (tour.*, bt.command_rejected)."""
        kind = ev.get("kind")
        detail = ev.get("detail") or {}
        job = self._job_of(rover, str(detail.get("request_id", "")))
        if job is None:
            return
        if kind == "tour.started" and job.state == "sent":
            job.state, job.started_wall_s = "running", now
            self._note("dispatch.started", job)
        elif kind == "tour.finished":
            job.state, job.ended_wall_s = "done", now
            self._note("dispatch.done", job, stops=detail.get("stops_reached"))
        elif kind == "tour.stopped" and rover not in job.stopping:
            self._redispatch(job, f"the tour stopped on {rover}: {detail.get('reason', '')}",
                             now, stop=False)
        elif kind == "bt.command_rejected" and detail.get("action") == "start_tour":
            self._redispatch(job, f"{rover} refused: {detail.get('message', '')}", now,
                             stop=False)

    def on_reply(self, rover: str, reply: dict[str, Any], now: float) -> None:
        """A rover's reply to a command."""
        job = self._job_of(rover, str(reply.get("request_id", "")))
        if job is not None and not reply.get("ok", False) and job.state == "sent":
            self._redispatch(job, f"{rover} refused: {reply.get('reason', '')}", now, stop=False)

    def rover_back(self, rover: str, now: float) -> None:
        """``rover`` is online again: if it still runs a tour another rover took, stop it."""
        tour_id = self.orphans.get(rover)
        r = self.roster.get(rover)
        if tour_id is not None and r.tour_id == tour_id:
            self.send(rover, {"action": "stop_tour", "request_id": f"orphan-{rover}-{now:.0f}"})
            self.send(rover, {"action": r.home_action,
                              "request_id": f"home-{rover}-{now:.0f}"})
            self.note("dispatch.orphan_stopped", {"rover": rover, "tour_id": tour_id})
        self.orphans.pop(rover, None)

    # --- the periodic check -----------------------------------------------------------------
    def tick(self, now: float) -> None:
        """Watch the jobs on their rovers, then give queued jobs to rovers."""
        for job in [j for j in self.jobs if j.state in ("sent", "running")]:
            self._watch(job, now)
        for job in [j for j in self.jobs if j.state == "queued"]:
            self._assign(job, now)

    def _watch(self, job: Job, now: float) -> None:
        cfg = self.cfg
        assert job.rover is not None
        r = self.roster.get(job.rover)
        online = r.online(now, cfg.offline_after_s)
        if not online:
            since = r.offline_since if r.offline_since is not None else now
            if now - since >= cfg.redispatch_after_s:
                if job.state == "running":
                    self.orphans[job.rover] = job.tour_id
                self._redispatch(job, f"{job.rover} has been offline for "
                                      f"{now - since:.0f} s", now, stop=False)
            return
        if job.state == "sent":
            if now - job.sent_wall_s > cfg.ack_timeout_s:
                self._redispatch(job, f"{job.rover} did not start it within "
                                      f"{cfg.ack_timeout_s:g} s", now, stop=True)
            elif now - job.last_send_wall_s > RESEND_S:
                self._send_start(job, now)
            return
        low = _low_battery(r, cfg)
        if low:
            self._redispatch(job, f"{job.rover}'s battery is low ({low})", now, stop=True)
            return
        failed = r.status.get("tour_phase") == "failed"
        job.failed_since = (job.failed_since or now) if failed else None
        if job.failed_since is not None and now - job.failed_since >= cfg.failed_tour_s:
            self._redispatch(job, f"the tour has been failed on {job.rover} for "
                                  f"{now - job.failed_since:.0f} s", now, stop=True)

    def _redispatch(self, job: Job, reason: str, now: float, *, stop: bool) -> None:
        old = job.rover
        if stop and old is not None:
            job.stopping.add(old)
            self.send(old, {"action": "stop_tour", "request_id": f"{job.request_id}-stop"})
            self.send(old, {"action": self.roster.get(old).home_action,
                            "request_id": f"{job.request_id}-home"})
        if old is not None:
            job.excluded.add(old)
        self.redispatches += 1
        self._note("dispatch.redispatch", job, reason=reason)
        job.reason = reason
        job.rover, job.request_id, job.failed_since = None, "", None
        job.state = "queued"
        job.deadline_wall_s = max(job.deadline_wall_s, now + self.cfg.start_window_s)
        if job.attempts >= self.cfg.max_attempts:
            self._drop(job, f"{job.attempts} attempts failed; last: {reason}")

    def _drop(self, job: Job, reason: str) -> None:
        job.state, job.reason = "dropped", reason
        self._note("dispatch.dropped", job, reason=reason)

    def candidates(self, job: Job, now: float) -> list[tuple[float, float, float, str]]:
        """(distance m, −state of charge (1 when unknown), −battery V, name) of every rover
        that may take ``job``, best first: the nearest (distances within ``NEAR_EQUAL_M`` count
        as equal), then the fuller battery, then the name."""
        busy = {j.rover for j in self.jobs if j.state in ("sent", "running")}
        out = []
        for r in self.roster.rovers.values():
            battery = r.battery
            if (r.name in busy or r.name in job.excluded or r.name in self.orphans
                    or not r.online(now, self.cfg.offline_after_s) or not r.ready
                    or battery is None or battery < self.cfg.min_battery_v):
                continue
            soc = r.soc
            if soc is not None and soc < self.cfg.min_soc:
                continue
            out.append((self.distance(r, job.tour_id), -(soc if soc is not None else -1.0),
                        -battery, r.name))
        return sorted(out, key=lambda c: (c[0] // NEAR_EQUAL_M if math.isfinite(c[0])
                                          else math.inf, c[1], c[2], c[3]))

    def _assign(self, job: Job, now: float) -> None:
        if now > job.deadline_wall_s:
            self._drop(job, job.reason or "no rover was ready within the start window")
            return
        try:
            self.tour_def(job.tour_id)
        except KeyError:
            self._drop(job, f"tour {job.tour_id} no longer exists")
            return
        best = next((c for c in self.candidates(job, now) if math.isfinite(c[0])), None)
        if best is None:
            return
        job.rover = best[3]
        job.attempts += 1
        job.request_id = f"job{job.id}-{job.attempts}"
        job.state, job.sent_wall_s = "sent", now
        self._send_start(job, now)
        self._note("dispatch.sent", job, distance_m=round(best[0], 2),
                   battery_v=round(-best[2], 2), soc=None if best[1] > 0 else -best[1])

    def _send_start(self, job: Job, now: float) -> None:
        assert job.rover is not None
        job.last_send_wall_s = now
        self.send(job.rover, {"action": "start_tour", "tour_id": job.tour_id,
                              "tour": self.tour_def(job.tour_id),
                              "request_id": job.request_id})


def _low_battery(r: RoverState, cfg: FleetManagerConfig) -> str:
    """Why ``r``'s battery is too low to go on with a tour ('' = it is not): its voltage under
    ``low_battery_v``, its state of charge under ``low_soc``, or its power model's level
    ``low`` / ``critical``."""
    battery, soc = r.battery, r.soc
    if battery is not None and battery < cfg.low_battery_v:
        return f"{battery:.2f} V"
    if soc is not None and soc < cfg.low_soc:
        return f"{soc:.0%} charge"
    level = r.status.get("power_level")
    if level in ("low", "critical"):
        return f"level {level}"
    return ""
