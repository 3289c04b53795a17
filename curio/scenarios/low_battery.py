"""Scenario ``low-battery``: mid-tour the battery runs low; the rover docks, charges, undocks
and runs the next scheduled tour.

On the default building with a dock at home (``dock.enabled``; the simulator puts the dock's
shape and charging contact there) and the tour tree: an operator authors the tour *Highlights*
(lobby, gallery) and schedules it at 10:00 and 10:15 (building time, ``tours.timezone``). The
rover starts on its dock. The 10:00 tour starts (it undocks first); when the first stop is
reached the pack is made to run down fast (the script sets the resting voltage to
``DRAIN_FROM_V`` and a drain of ``DRAIN_V_PER_H``, as an old pack sagging under load would);
below ``bt.low_battery_v`` the rover abandons the tour (``tour.stopped``, ``battery.low``),
drives to the dock's staging pose and docks on the dock's shape (``dock.*``). On the dock the
simulated charger charges it (at ``dock.charge_rate_v_per_h`` = ``CHARGE_V_PER_H``: hours of
charging pass in seconds, the one thing accelerated); at ``bt.battery_ok_v`` it is ready again.
While it sits docked and charged with nothing due, the building's clock jumps to just before the
next scheduled start (``SimClock.jump_wall``, as ``tour-day`` does). The 10:15 tour starts
(undock, both stops), and after it the rover goes home and docks again.

Metrics (DESIGN.md): ``dock_attempts`` (approaches, all dockings), ``dock_successes``,
``dock_error_m`` and ``dock_error_deg`` (the largest ground-truth error of the rover against
the dock's docked pose over the dockings), ``min_battery_v`` (the lowest ``/battery`` reading);
also ``dockings`` (each one's attempts and errors), ``charged_to_v`` and ``time_lapse_s``.
Success: the first tour stopped for the battery, docked and charged before the second tour,
undocked for it, the second tour finished, docked again, dock errors within 2 cm and 2°, no
collision.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass, field
from typing import Any
from zoneinfo import ZoneInfo

from curio.core.config import Config
from curio.core.messages import Event
from curio.core.topics import BATTERY, EVENTS, STATUS, TOUR
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed
from curio.tours.scheduler import READY_STATES

__all__ = ["LowBatteryScenario"]

DAY = dt.date(2025, 6, 2)  # a Monday
TIMES = ["10:00", "10:15"]
STOPS = [
    {"name": "Lobby", "x_m": 2.0, "y_m": -2.5, "dwell_s": 5.0,
     "message": "Welcome to the Curio building!"},
    {"name": "Gallery", "x_m": 12.5, "y_m": 1.5, "dwell_s": 5.0,
     "message": "This is the gallery."},
]
DRAIN_FROM_V = 6.75
DRAIN_V_PER_H = 30.0
CHARGE_V_PER_H = 120.0
LEAD_S = 20.0
MAX_ERROR_M = 0.02
MAX_ERROR_DEG = 2.0


def _at(hhmm: str, tz: ZoneInfo) -> float:
    return dt.datetime.combine(DAY, dt.time.fromisoformat(hhmm), tzinfo=tz).timestamp()


@dataclass
class _Run:
    tz: ZoneInfo
    events: list[Event] = field(default_factory=list)
    drained: bool = False
    min_v: float = math.inf
    dockings: list[dict[str, Any]] = field(default_factory=list)
    lapse_s: float = 0.0

    def of(self, kind: str) -> list[Event]:
        return [e for e in self.events if e.kind == kind]


class LowBatteryScenario(Scenario):
    """The battery runs low mid-tour (see the module docstring)."""

    name = "low-battery"
    description = "mid-tour the battery runs low: dock, charge, undock, the next scheduled tour"
    default_duration_s = 1800.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """The tour tree, a dock at home, a fast simulated charger; the Arduino's A0 reads the
        dock's contacts in emulated mode."""
        bt = cfg.bt.model_copy(update={"tree": "tour", "autostart_path": None, "speak": False,
                                       "tour_stops": [], "tour_loop": False})
        dock = cfg.dock.model_copy(update={"enabled": True,
                                           "charge_rate_v_per_h": CHARGE_V_PER_H})
        arduino = cfg.drivers.arduino.model_copy(update={"adc_is_charger": True})
        drivers = cfg.drivers.model_copy(update={"arduino": arduino})
        return cfg.model_copy(update={"bt": bt, "dock": dock, "drivers": drivers})

    def wall_epoch_s(self, cfg: Config) -> float | None:
        """The morning starts at 09:59:30 in the building's time zone."""
        return _at("09:59:30", ZoneInfo(cfg.tours.timezone))

    async def run(self, ctx: ScenarioContext) -> None:
        """Author and schedule, run until the second tour is home, score."""
        run = _Run(ZoneInfo(ctx.cfg.tours.timezone))
        svc = ctx.app.tours.service
        tour = svc.create_tour("Highlights", STOPS, actor="scenario")
        svc.add_schedule(tour.id, [DAY.strftime("%a").lower()], TIMES, actor="scenario")
        await ctx.navigator_ready(30.0)
        if ctx.app.docker is None or not ctx.app.docker.docked:
            raise ScenarioFailed("the rover did not start on its dock")
        events = ctx.bus.subscribe(EVENTS)
        battery = ctx.bus.subscribe(BATTERY, maxsize=1000)
        try:
            await self._loop(ctx, run, events, battery)
        finally:
            run.events.extend(events.drain())
            events.close()
            battery.close()
        self._score(ctx, run)

    async def _loop(self, ctx: ScenarioContext, run: _Run, events: Any, battery: Any) -> None:
        limit = ctx.now() + (ctx.args.duration_s or self.default_duration_s) - 10.0
        while ctx.now() < limit:
            run.events.extend(events.drain())
            for b in battery.drain():
                run.min_v = min(run.min_v, b.voltage_v)
            self._drain(ctx, run)
            self._note_dockings(ctx, run)
            if len(run.of("tour.finished")) >= 1 and len(run.dockings) >= 2:
                return
            if self._parked(ctx, run):
                now = ctx.clock.wall_time()
                # From the scheduler's last check: a start due but not yet seen counts.
                seen = ctx.app.tours.scheduler.last_check_wall_s
                nxt = ctx.app.tours.schedules.next_occurrence(min(now, seen or now))
                if nxt is not None and nxt.wall_s - now > LEAD_S + 5.0:
                    jump = nxt.wall_s - LEAD_S - now
                    ctx.clock.jump_wall(jump)
                    run.lapse_s += jump
                    continue
            await ctx.sleep(0.5)
        status = ctx.bus.latest(STATUS)
        raise ScenarioFailed(f"the second tour did not end docked within the time limit; "
                             f"status: {status.text if status else None}")

    @staticmethod
    def _drain(ctx: ScenarioContext, run: _Run) -> None:
        world = ctx.world
        if not run.drained and run.of("tour.stop"):
            run.drained = True
            world.set_battery_voltage(DRAIN_FROM_V)
            world.battery_drain_v_per_h = DRAIN_V_PER_H
            ctx.record("script", action="the pack runs down", from_v=DRAIN_FROM_V,
                       drain_v_per_h=DRAIN_V_PER_H)
        if run.drained and run.of("battery.low") and world.battery_drain_v_per_h > 1.0:
            world.battery_drain_v_per_h = 0.3  # the sag is over: an ordinary discharge again

    @staticmethod
    def _note_dockings(ctx: ScenarioContext, run: _Run) -> None:
        docked = [e for e in run.of("dock.docked") if e.detail.get("attempts")]
        while len(run.dockings) < len(docked):
            ev = docked[len(run.dockings)]
            world = ctx.world
            dx, dy, dyaw = world.dock.error(world.truth_pose)
            run.dockings.append({"t": round(ev.stamp, 1), "attempts": ev.detail["attempts"],
                                 "error_m": round(math.hypot(dx, dy), 4),
                                 "error_deg": round(abs(math.degrees(dyaw)), 3),
                                 "reason": ev.detail.get("reason", ""),
                                 "contact": bool(world.docked)})

    @staticmethod
    def _parked(ctx: ScenarioContext, run: _Run) -> bool:
        status = ctx.bus.latest(STATUS)
        tour = ctx.bus.latest(TOUR)
        bat = ctx.bus.latest(BATTERY)
        return (status is not None and status.state in READY_STATES
                and status.state in ("docked", "charging")
                and (tour is None or tour.tour_id is None)
                and bat is not None and bat.voltage_v >= ctx.cfg.tours.min_battery_v
                and not ctx.app.tours.scheduler.pending and bool(run.of("battery.ok")))

    def _score(self, ctx: ScenarioContext, run: _Run) -> None:
        stopped = run.of("tour.stopped")
        finished = run.of("tour.finished")
        low = run.of("battery.low")
        undocked = run.of("dock.undocked")
        attempts = sum(1 for _ in run.of("dock.attempt"))
        worst_m = max((d["error_m"] for d in run.dockings), default=None)
        worst_deg = max((d["error_deg"] for d in run.dockings), default=None)
        ctx.check("the battery ran low during the first tour",
                  bool(low) and bool(stopped) and low[0].stamp <= stopped[0].stamp + 1.0,
                  f"{len(low)} low, {len(stopped)} stopped")
        first_dock = run.dockings[0]["t"] if run.dockings else math.inf
        charged = [e for e in run.of("battery.ok") if e.stamp >= first_dock]
        ctx.check("docked and charged before the next tour", bool(charged) and len(
            run.of("tour.started")) >= 2 and charged[0].stamp <= run.of("tour.started")[1].stamp,
            f"dockings {run.dockings}")
        ctx.check("undocked before each tour", len(undocked) >= 2, f"{len(undocked)} undockings")
        ctx.check("the next scheduled tour finished", len(finished) >= 1,
                  f"{len(finished)} finished")
        ctx.check("docked again after it", len(run.dockings) >= 2, str(run.dockings))
        ctx.check("every docking within 2 cm and 2 deg", worst_m is not None
                  and worst_m <= MAX_ERROR_M and worst_deg is not None
                  and worst_deg <= MAX_ERROR_DEG, f"worst {worst_m} m, {worst_deg} deg")
        ctx.check("no collision", not run.of("collision"),
                  str([e.detail for e in run.of("collision")]))
        ctx.goals_total = 2 * len(STOPS)
        ctx.goals_reached = len(run.of("tour.stop"))
        ctx.metrics.update({
            "dock_attempts": attempts,
            "dock_successes": len(run.dockings),
            "dock_error_m": worst_m,
            "dock_error_deg": worst_deg,
            "min_battery_v": round(run.min_v, 3) if math.isfinite(run.min_v) else None,
            "dockings": run.dockings,
            "charged_to_v": round(max((e.detail.get("voltage_v", 0.0) for e in charged),
                                      default=0.0), 3),
            "time_lapse_s": round(run.lapse_s, 1),
            "tour_stop_reason": stopped[0].detail.get("reason") if stopped else None,
        })
