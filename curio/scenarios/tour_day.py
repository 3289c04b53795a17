"""The ``tour-day`` scenario: a simulated opening day of the tour guide, 09:00 to 18:00.

On the default building (``maps/curio_building``) an operator authors two tours through the
tour service — *Highlights* (lobby, gallery) and *North wing* (library, meeting room) — and a
schedule of six (Highlights at 09:30, 11:30 and 14:30, North wing at 10:30, 13:00 and 16:00,
on the day's weekday) in the building's time zone (``tours.timezone``). Visitors start two more
at the kiosk (through :meth:`TourService.start_tour` with ``source="kiosk"``, as the kiosk page
will): Highlights at 10:50, and North wing at 14:29:50 — which is still running when the 14:30
tour is due, so that one is delayed and then skipped with the reason. At 12:55 the library door
is locked in front of the rover on the 13:00 tour (when it comes within ``DOOR_M`` of it): the
rover asks for help, and a member of staff opens the door ``HELP_ANSWER_S`` after the request.
After every tour the rover drives home by itself (``tours.return_home``).

**Time-lapse.** Nine hours at the whole stack's ~30× real time would take a quarter of an hour,
so while the rover is parked at home with nothing to do, the building's clock
(``SimClock.jump_wall``) jumps to ``LEAD_S`` before the next thing that happens (a scheduled
tour, a visitor, the door, closing time). Nothing that moves is skipped: every tour, every way
home and every wait is simulated in full; ``metrics.time_lapse_s`` says how much idle time was
jumped. (The skipped stretches drain no battery: the rover would be on its charger at home.)

Metrics: ``tours_scheduled`` (starts the schedule had for the day), ``tours_completed`` (tours
that finished, scheduled or not), ``tours_skipped``, ``stops_visited``, ``help_requests``,
``events_logged`` (the day's records in the event log) and the daily ``report``.
Success: every scheduled start ran or was skipped with a reason, every started tour ended, no
collision, the rover home at 18:00.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any
from zoneinfo import ZoneInfo

from curio.core.config import Config
from curio.core.messages import Event
from curio.core.topics import EVENTS, STATUS, TOUR
from curio.eventlog.report import daily_report
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed
from curio.tours.model import TourError
from curio.tours.scheduler import READY_STATES

__all__ = ["TourDayScenario"]

DAY = dt.date(2025, 6, 2)  # a Monday
OPEN, CLOSE = "09:00", "18:00"
LEAD_S = 30.0
HELP_ANSWER_S = 30.0
DOOR = "library"
DOOR_M = 2.6

HIGHLIGHTS = [
    {"name": "Lobby", "x_m": 2.0, "y_m": -2.5, "dwell_s": 10.0,
     "message": "Welcome to the Curio building! I am Curio, your guide today."},
    {"name": "Gallery", "x_m": 12.5, "y_m": 1.5, "dwell_s": 10.0,
     "message": "This is the gallery: the plinths show the rover's history."},
]
NORTH_WING = [
    {"name": "Library", "x_m": 1.0, "y_m": 11.8, "dwell_s": 10.0,
     "message": {"text": "Bienvenue à la bibliothèque.", "language": "fr"}},
    {"name": "Meeting room", "x_m": 19.5, "y_m": 12.0, "dwell_s": 10.0,
     "message": "The meeting room: teams plan their missions here."},
]
SCHEDULE = [("Highlights", ["09:30", "11:30", "14:30"]), ("North wing", ["10:30", "13:00",
                                                                           "16:00"])]
VISITORS = [("10:50:00", "Highlights"), ("14:29:50", "North wing")]


def _at(hhmm: str, tz: ZoneInfo) -> float:
    t = dt.time.fromisoformat(hhmm)
    return dt.datetime.combine(DAY, t, tzinfo=tz).timestamp()


@dataclass
class _Day:
    """What the script keeps track of during the day."""

    tz: ZoneInfo
    tour_ids: dict[str, int] = field(default_factory=dict)
    visitors: list[tuple[float, str]] = field(default_factory=list)
    door_closes_at: float = 0.0
    door_closed: bool = False
    door_opened: bool = False
    help_at: float | None = None
    lapse_s: float = 0.0
    hold_until: float = 0.0
    kiosk_refusals: list[str] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)


class TourDayScenario(Scenario):
    """A simulated opening day (see the module docstring)."""

    name = "tour-day"
    description = ("an opening day 09:00-18:00: two tours, six scheduled, two started at the "
                   "kiosk, a locked door, home between tours")
    default_duration_s = 4 * 3600.0
    time_lapse = True
    schedule: Sequence[tuple[str, Sequence[str]]] = SCHEDULE
    visitors: Sequence[tuple[str, str]] = VISITORS
    close = CLOSE
    door: str | None = DOOR
    expect_skipped = "14:30"

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """The tour tree without speech; tours come from the script, not bt.tour_stops."""
        bt = cfg.bt.model_copy(update={"tree": "tour", "autostart_path": None, "speak": False,
                                       "tour_stops": [], "tour_loop": False})
        return cfg.model_copy(update={"bt": bt})

    def wall_epoch_s(self, cfg: Config) -> float | None:
        """The day starts at 08:59 in the building's time zone."""
        return _at("08:59", ZoneInfo(cfg.tours.timezone))

    async def run(self, ctx: ScenarioContext) -> None:
        """Author, schedule, run the day, then score it."""
        day = _Day(ZoneInfo(ctx.cfg.tours.timezone))
        svc = ctx.app.tours.service
        for name, stops in (("Highlights", HIGHLIGHTS), ("North wing", NORTH_WING)):
            day.tour_ids[name] = svc.create_tour(name, stops, actor="scenario").id
        for name, times in self.schedule:
            svc.add_schedule(day.tour_ids[name], [DAY.strftime("%a").lower()], times,
                             actor="scenario")
        day.visitors = [(_at(t, day.tz), name) for t, name in self.visitors]
        day.door_closes_at = _at("12:55", day.tz)
        await ctx.navigator_ready(30.0)
        sub = ctx.bus.subscribe(EVENTS)
        try:
            await self._day(ctx, day, sub)
            await ctx.sleep(1.0)  # the recorder logs the last records
        finally:
            day.events.extend(sub.drain())
            sub.close()
        self._score(ctx, day)

    # --- the day ------------------------------------------------------------------------------

    async def _day(self, ctx: ScenarioContext, day: _Day, sub: Any) -> None:
        end = _at(self.close, day.tz)
        while ctx.clock.wall_time() < end:
            day.events.extend(sub.drain())
            now = ctx.clock.wall_time()
            self._visitors(ctx, day, now)
            self._door(ctx, day, now)
            if self.time_lapse and self._parked(ctx, day):
                nxt = self._next_thing(ctx, day, now, end)
                if nxt - now > LEAD_S + 5.0:
                    ctx.clock.jump_wall(nxt - LEAD_S - now)
                    day.lapse_s += nxt - LEAD_S - now
                    continue
            await ctx.sleep(1.0)
        # Closing time: let a tour that is still out come home.
        await ctx.wait_until(lambda: self._parked(ctx, day), 900.0, poll_s=1.0)

    def _visitors(self, ctx: ScenarioContext, day: _Day, now: float) -> None:
        while day.visitors and day.visitors[0][0] <= now:
            _, name = day.visitors.pop(0)
            try:
                ctx.app.tours.service.start_tour(day.tour_ids[name], source="kiosk")
                ctx.record("script", action="visitor starts a tour", tour=name)
                day.hold_until = ctx.now() + 3.0  # no time-lapse before the tour starts
            except TourError as exc:
                day.kiosk_refusals.append(str(exc))
                ctx.record("script", action="kiosk refused", tour=name, reason=str(exc))

    def _door(self, ctx: ScenarioContext, day: _Day, now: float) -> None:
        if self.door is None:
            return
        if not day.door_closed and now >= day.door_closes_at and self._near_door(ctx, self.door):
            ctx.world.set_door(self.door, False)
            day.door_closed = True
            ctx.record("script", action="door locked", door=self.door)
        if day.help_at is None and any(e.kind == "help.requested" for e in day.events):
            day.help_at = ctx.now()
        if (day.door_closed and not day.door_opened and day.help_at is not None
                and ctx.now() - day.help_at >= HELP_ANSWER_S):
            ctx.world.set_door(self.door, True)
            day.door_opened = True
            ctx.record("script", action="staff opens the door", door=self.door)

    @staticmethod
    def _near_door(ctx: ScenarioContext, name: str) -> bool:
        door = ctx.world.door(name)
        truth = ctx.truth()
        return truth is not None and math.hypot(truth.x - (door.a[0] + door.b[0]) / 2.0,
                                                truth.y - (door.a[1] + door.b[1]) / 2.0) < DOOR_M

    def _parked(self, ctx: ScenarioContext, day: _Day) -> bool:
        """At home, idle, no tour running or waiting to start, no help open."""
        status = ctx.bus.latest(STATUS)
        tour = ctx.bus.latest(TOUR)
        truth = ctx.truth()
        home = ctx.app.robot.home
        return (ctx.now() >= day.hold_until
                and status is not None and status.state in READY_STATES
                and (tour is None or tour.tour_id is None)
                and not ctx.app.tours.scheduler.pending
                and truth is not None and truth.distance_to(home) < 0.5
                and (day.help_at is None or day.door_opened))

    def _next_thing(self, ctx: ScenarioContext, day: _Day, now: float, end: float) -> float:
        times = [end]
        # From the scheduler's last check: a start that is due but not yet seen counts.
        seen = ctx.app.tours.scheduler.last_check_wall_s
        nxt = ctx.app.tours.schedules.next_occurrence(min(now, seen if seen else now))
        if nxt is not None:
            times.append(nxt.wall_s)
        times += [t for t, _ in day.visitors]
        return min(times)

    # --- scoring ------------------------------------------------------------------------------

    def _score(self, ctx: ScenarioContext, day: _Day) -> None:
        events = day.events

        def of(kind: str) -> list[Event]:
            return [e for e in events if e.kind == kind]

        since, until = _at(OPEN, day.tz), _at(self.close, day.tz)
        due = ctx.app.tours.schedules.occurrences(since - 1.0, until)
        started = {e.detail["due"] for e in of("tour.scheduled_start")}
        skipped = {e.detail["due"]: e.detail.get("reason", "") for e in of("tour.skipped")}
        labels = [o.local.isoformat(timespec="minutes") for o in due]
        unaccounted = [lab for lab in labels if lab not in started and not skipped.get(lab)]
        ctx.check("every scheduled tour ran or was skipped with a reason", not unaccounted,
                  f"{len(started)} started, {len(skipped)} skipped, unaccounted {unaccounted}")
        if self.expect_skipped:
            ctx.check(f"the {self.expect_skipped} tour was skipped while the visitors' tour ran",
                      any(f"T{self.expect_skipped}" in lab for lab in skipped), str(skipped))
        ended = len(of("tour.finished")) + len(of("tour.stopped"))
        ctx.check("every started tour ended", len(of("tour.started")) == ended,
                  f"{len(of('tour.started'))} started, {ended} ended")
        opened = [e for e in of("script") if e.detail.get("action") == "staff opens the door"]
        if self.door is not None:
            ctx.check("help asked at the locked door, resolved after it opened",
                      bool(of("help.requested")) and bool(opened)
                      and bool(of("help.resolved"))
                      and of("help.resolved")[-1].stamp >= opened[0].stamp,
                      f"{len(of('help.requested'))} requests")
        ctx.check("no collision", not of("collision"), str([e.detail for e in of("collision")]))
        truth = ctx.truth()
        home = ctx.app.robot.home
        ctx.check("home at closing time", truth is not None and truth.distance_to(home) < 0.5,
                  f"{truth.distance_to(home):.2f} m from home" if truth else "no pose")
        ctx.check("visitors' tours accepted at the kiosk", not day.kiosk_refusals,
                  "; ".join(day.kiosk_refusals))
        ctx.goals_total = len(due) + len(self.visitors)
        ctx.goals_reached = len(of("tour.finished"))
        self._metrics(ctx, day, len(due), events)

    def _metrics(self, ctx: ScenarioContext, day: _Day, scheduled: int,
                 events: list[Event]) -> None:
        log = ctx.app.eventlog
        report: dict[str, Any] = {}
        logged = 0
        if log is not None:
            if not log.flush():
                raise ScenarioFailed("the event log did not flush")
            rep = daily_report(log, DAY, day.tz)
            logged = rep.events
            report = {k: v for k, v in rep.to_json().items()
                      if k not in ("tours", "skipped", "fault_list", "help_waits_s")}
        ctx.metrics.update({
            "tours_scheduled": scheduled,
            "tours_completed": sum(1 for e in events if e.kind == "tour.finished"),
            "tours_skipped": sum(1 for e in events if e.kind == "tour.skipped"),
            "stops_visited": sum(1 for e in events if e.kind == "tour.stop"),
            "help_requests": sum(1 for e in events if e.kind == "help.requested"),
            "events_logged": logged,
            "time_lapse_s": round(day.lapse_s, 1),
            "day_s": round(_at(self.close, day.tz) - _at(OPEN, day.tz), 1),
            "skip_reasons": [e.detail.get("reason", "") for e in events
                             if e.kind == "tour.skipped"],
            "report": report,
        })
