"""The fleet's ``tour-day``: three rovers share the default building for an opening day.

09:00-18:00 on Monday 2 June 2025 in the building's time zone. The fleet manager holds five
tours (Highlights: lobby, gallery; Gallery first: gallery, lobby; North wing: library, meeting
room; East wing: lab, workshop; Workshop: workshop, library) and a schedule of ten starts, in
pairs at the same time chosen so that the rovers are out together and cross the same doorways
(the gallery's 1.2 m door, the workshop's 0.9 m doorway) in opposite directions; two groups of
visitors ask for the workshop tour at the kiosk 45 s apart. Every tour is dispatched by
the manager to the best rover (idle, charged, nearest); after a tour the rover drives home by
itself. The rovers' homes are side by side in the lobby.

As in the single-rover ``tour-day`` the building's clock jumps over the stretches in which every
rover is parked at home with nothing to do (``time_lapse_s``); everything that moves is
simulated in full.

Metrics (besides the fleet report's ``rover_rover_collisions``, ``rover_rover_encounters``,
``longest_standoff_s`` and the link rates): ``tours_requested``, ``tours_scheduled``,
``tours_completed``, ``tours_dropped``, ``redispatches``, ``per_rover_tours``, ``time_lapse_s``.
Success: every requested tour completed or was dropped with a reason, no rover-rover collision,
every rover home at closing time.
"""

from __future__ import annotations

import datetime as dt
import logging
from typing import Any
from zoneinfo import ZoneInfo

from curio.core.config import Config
from curio.core.topics import STATUS
from curio.scenarios.fleet.base import FleetArgs, FleetContext, FleetScenario
from curio.tours.model import TourError, stop_from_json
from curio.tours.scheduler import READY_STATES

__all__ = ["FleetTourDay"]

log = logging.getLogger("curio.fleet.sim")

DAY = dt.date(2025, 6, 2)
OPEN, CLOSE = "09:00", "18:00"
LEAD_S = 30.0
HOMES = [(0.0, 0.0, 0.0), (0.0, 2.5, 0.0), (0.0, -2.5, 0.0), (-2.5, 0.0, 0.0),
         (-2.5, 2.5, 0.0), (-2.0, -2.5, 0.0)]

LOBBY = {"name": "Lobby", "x_m": 2.0, "y_m": -2.5, "dwell_s": 10.0,
         "message": "Welcome to the Curio building!"}
GALLERY = {"name": "Gallery", "x_m": 12.5, "y_m": 1.5, "dwell_s": 10.0,
           "message": "The gallery: the rover's history."}
LIBRARY = {"name": "Library", "x_m": 1.0, "y_m": 11.8, "dwell_s": 10.0,
           "message": {"text": "Bienvenue à la bibliothèque.", "language": "fr"}}
MEETING = {"name": "Meeting room", "x_m": 19.5, "y_m": 12.0, "dwell_s": 10.0,
           "message": "The meeting room."}
LAB = {"name": "Lab", "x_m": 20.0, "y_m": 0.0, "dwell_s": 10.0,
       "message": "The lab, where the electronics are built."}
WORKSHOP = {"name": "Workshop", "x_m": 8.6, "y_m": 12.2, "dwell_s": 10.0,
            "message": "The workshop, behind its narrow door."}
TOURS: dict[str, list[dict[str, Any]]] = {
    "Highlights": [LOBBY, GALLERY], "Gallery first": [GALLERY, LOBBY],
    "North wing": [LIBRARY, MEETING], "East wing": [LAB, WORKSHOP],
    "Workshop": [WORKSHOP, LIBRARY]}
# Tours that cross the same doorways in opposite directions start together.
SCHEDULE = [("Highlights", ["09:30", "12:30"]), ("Gallery first", ["09:30", "12:30"]),
            ("East wing", ["09:35", "14:30"]), ("North wing", ["11:00", "14:30"]),
            ("Workshop", ["11:00", "12:35"])]
# Two groups of visitors ask for the workshop 45 s apart: the second rover meets the first at
# the workshop's doorway as it comes out.
KIOSK = [("10:40:00", "Workshop"), ("10:40:45", "Workshop")]


def _at(hhmm: str, tz: ZoneInfo) -> float:
    return dt.datetime.combine(DAY, dt.time.fromisoformat(hhmm), tzinfo=tz).timestamp()


class FleetTourDay(FleetScenario):
    """An opening day of a fleet (see the module docstring)."""

    name = "tour-day"
    description = "an opening day 09:00-18:00: 12 tours dispatched across the fleet"
    default_rovers = 3
    default_duration_s = 6 * 3600.0
    wants_manager = True
    close = CLOSE

    def starts(self, n: int, seed: int) -> list[tuple[float, float, float]]:
        """Homes side by side in the lobby."""
        if not 1 <= n <= len(HOMES):
            raise ValueError(f"the fleet tour-day has 1 to {len(HOMES)} rovers, not {n}")
        return HOMES[:n]

    def configure(self, cfg: Config, args: FleetArgs) -> Config:
        """The tour tree, no speech, no tours of their own (the manager sends them)."""
        bt = cfg.bt.model_copy(update={"tree": "tour", "autostart_path": None, "speak": False,
                                       "tour_stops": [], "tour_loop": False})
        return cfg.model_copy(update={"bt": bt})

    def tours(self) -> dict[str, list[dict[str, Any]]]:
        """The day's five tours."""
        return {name: list(stops) for name, stops in TOURS.items()}

    def wall_epoch_s(self, cfg: Config) -> float | None:
        """08:59 in the building's time zone."""
        return _at("08:59", ZoneInfo(cfg.tours.timezone))

    async def run(self, ctx: FleetContext) -> None:
        """Author, schedule, run the day, score it."""
        mgr = ctx.manager
        tz = ZoneInfo(ctx.cfg.tours.timezone)
        ids = {}
        for name, stops in self.tours().items():
            ids[name] = mgr.tours.create(name, [stop_from_json(s) for s in stops],
                                         actor="scenario").id
        weekday = DAY.strftime("%a").lower()
        for name, times in SCHEDULE:
            mgr.schedules.add(ids[name], [weekday], times, actor="scenario")
        kiosk = [(_at(t, tz), name) for t, name in KIOSK]
        lapse = await self._day(ctx, ids, kiosk, tz)
        self._score(ctx, tz, lapse)

    async def _day(self, ctx: FleetContext, ids: dict[str, int],
                   kiosk: list[tuple[float, str]], tz: ZoneInfo) -> float:
        mgr = ctx.manager
        end = _at(self.close, tz)
        lapse = 0.0
        hold_until = 0.0
        await ctx.sleep(3.0)
        next_report = 0.0
        while ctx.clock.wall_time() < end:
            now = ctx.clock.wall_time()
            if ctx.now() >= next_report:
                next_report = ctx.now() + 300.0
                log.info("fleet tour-day: %s, %.0f s simulated, jobs %s",
                         dt.datetime.fromtimestamp(now, tz).strftime("%H:%M"), ctx.now(),
                         ctx.manager.summary()["by_state"])
            while kiosk and kiosk[0][0] <= now:
                _, name = kiosk.pop(0)
                try:
                    mgr.dispatch_tour(ids[name], "kiosk")
                    ctx.record("script", action="visitor asks for a tour", tour=name)
                except TourError as exc:
                    ctx.record("script", action="kiosk refused", reason=str(exc))
                hold_until = ctx.now() + 5.0
            if ctx.now() >= hold_until and self._parked(ctx):
                nxt = self._next_thing(ctx, now, end, kiosk)
                if nxt - now > LEAD_S + 5.0:
                    ctx.clock.jump_wall(nxt - LEAD_S - now)
                    lapse += nxt - LEAD_S - now
                    continue
            await ctx.sleep(1.0)
        await ctx.wait_until(lambda: self._parked(ctx), 1800.0, poll_s=1.0)
        return lapse

    @staticmethod
    def _parked(ctx: FleetContext) -> bool:
        """Every rover home and idle, no job open."""
        if ctx.manager.dispatcher.active():
            return False
        for r in ctx.rovers:
            status = r.app.bus.latest(STATUS)
            truth = ctx.truth(r.name)
            if (status is None or status.state not in READY_STATES
                    or r.app.tours.service.running() is not None or truth is None
                    or truth.distance_to(r.app.robot.home) > 0.6):
                return False
        return True

    @staticmethod
    def _next_thing(ctx: FleetContext, now: float, end: float,
                    kiosk: list[tuple[float, str]]) -> float:
        times = [end] + [t for t, _ in kiosk]
        # From the manager's last check: a start that is due but not yet seen counts.
        seen = ctx.manager.last_check_wall_s
        nxt = ctx.manager.schedules.next_occurrence(min(now, seen) if seen else now)
        if nxt is not None:
            times.append(nxt.wall_s)
        return min(times)

    def _score(self, ctx: FleetContext, tz: ZoneInfo, lapse: float) -> None:
        mgr = ctx.manager
        jobs = mgr.dispatcher.jobs
        done = [j for j in jobs if j.state == "done"]
        dropped = [j for j in jobs if j.state == "dropped"]
        open_jobs = [j for j in jobs if j.state in ("queued", "sent", "running")]
        scheduled = mgr.schedules.occurrences(_at(OPEN, tz) - 1.0, _at(self.close, tz))
        per_rover: dict[str, int] = {r.name: 0 for r in ctx.rovers}
        for j in done:
            if j.rover is not None:
                per_rover[j.rover] = per_rover.get(j.rover, 0) + 1
        ctx.metrics.update({
            "tours_requested": len(jobs), "tours_scheduled": len(scheduled),
            "tours_completed": len(done), "tours_dropped": len(dropped),
            "drop_reasons": [j.reason for j in dropped],
            "redispatches": mgr.dispatcher.redispatches, "per_rover_tours": per_rover,
            "time_lapse_s": round(lapse, 1),
            "jobs": [_job_line(j.to_json()) for j in jobs],
        })
        ctx.check("every requested tour completed or was dropped with a reason",
                  not open_jobs and all(j.reason for j in dropped),
                  f"{len(done)} done, {len(dropped)} dropped, {len(open_jobs)} open")
        ctx.check("no rover-rover collision", not ctx.rover_rover_collisions(),
                  str(ctx.rover_rover_collisions()[:3]))
        away = [r.name for r in ctx.rovers if (t := ctx.truth(r.name)) is None
                or t.distance_to(r.app.robot.home) > 0.6]
        ctx.check("every rover home at closing time", not away, f"away: {away}")


def _job_line(job: dict[str, Any]) -> dict[str, Any]:
    return {k: job[k] for k in ("id", "tour", "source", "state", "rover", "attempts", "reason")}
