"""The daily report, computed from the event log: what a museum's staff read each evening.

For one local day (midnight to midnight in ``tours.timezone``): tours run (who started them,
how they ended, stops reached), scheduled starts and skipped ones with why, stops visited,
distance driven and time moving (the ``motion`` records), help requests and the median wait
until help came, faults, e-stops and collisions, operator commands, and the day's record
count. :func:`daily_report` returns a :class:`DailyReport`; :func:`format_report` renders the
text ``curio report --day`` prints; ``to_json`` gives the dashboard's table and plots.
"""

from __future__ import annotations

import datetime as dt
import statistics
from dataclasses import asdict, dataclass, field
from typing import Any
from zoneinfo import ZoneInfo

from .store import EventLog, LogQuery, LogRecord

__all__ = ["DailyReport", "daily_report", "day_bounds", "format_report"]


def day_bounds(day: dt.date, tz: ZoneInfo) -> tuple[float, float]:
    """UNIX seconds of local midnight at the start and end of ``day`` (summer time aware)."""
    start = dt.datetime(day.year, day.month, day.day, tzinfo=tz)
    end = start.date() + dt.timedelta(days=1)
    return start.timestamp(), dt.datetime(end.year, end.month, end.day, tzinfo=tz).timestamp()


@dataclass
class DailyReport:
    """One day's figures (times local, seconds and metres)."""

    day: str
    timezone: str
    tours_started: int = 0
    tours_completed: int = 0
    tours_stopped: int = 0
    tours_interrupted: int = 0
    tours_scheduled: int = 0
    tours_scheduled_started: int = 0
    tours_skipped: int = 0
    stops_visited: int = 0
    distance_m: float = 0.0
    moving_s: float = 0.0
    help_requests: int = 0
    help_median_wait_s: float | None = None
    help_waits_s: list[float] = field(default_factory=list)
    faults: int = 0
    estops: int = 0
    collisions: int = 0
    operator_commands: int = 0
    events: int = 0
    tours: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    fault_list: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form (the dashboard's table and plots)."""
        return asdict(self)


def _clock(rec: LogRecord, tz: ZoneInfo) -> str:
    return dt.datetime.fromtimestamp(rec.wall_s, tz).strftime("%H:%M")


def _tour_row(rec: LogRecord, end: LogRecord | None, tz: ZoneInfo) -> dict[str, Any]:
    outcome = "running" if end is None else {"tour.finished": "completed",
                                             "tour.interrupted": "interrupted"}.get(
                                                 end.kind, "stopped")
    detail = end.detail if end is not None else {}
    return {"time": _clock(rec, tz), "tour": rec.detail.get("tour", ""),
            "source": str(rec.detail.get("source", "")).split(":")[0], "outcome": outcome,
            "reason": detail.get("reason", ""), "stops_reached": detail.get("stops_reached"),
            "stops": rec.detail.get("stops"), "duration_s": detail.get("duration_s")}


def daily_report(log: EventLog, day: dt.date, tz: ZoneInfo) -> DailyReport:
    """The report of ``day`` (local) from ``log``."""
    since, until = day_bounds(day, tz)
    records = log.query(LogQuery(since_wall_s=since, until_wall_s=until, limit=100_000))
    report = DailyReport(day.isoformat(), str(tz.key), events=len(records))
    open_tour: LogRecord | None = None
    for rec in records:
        kind = rec.kind
        if kind == "tour.started":
            if open_tour is not None:
                report.tours.append(_tour_row(open_tour, None, tz))
            open_tour = rec
            report.tours_started += 1
        elif kind in ("tour.finished", "tour.stopped", "tour.interrupted"):
            if kind == "tour.finished":
                report.tours_completed += 1
            elif kind == "tour.interrupted":
                report.tours_interrupted += 1
            else:
                report.tours_stopped += 1
            if open_tour is not None:
                report.tours.append(_tour_row(open_tour, rec, tz))
                open_tour = None
        else:
            _count(report, rec, tz)
    if open_tour is not None:
        report.tours.append(_tour_row(open_tour, None, tz))
    report.tours_scheduled = report.tours_scheduled_started + report.tours_skipped
    if report.help_waits_s:
        report.help_median_wait_s = round(statistics.median(report.help_waits_s), 1)
    report.distance_m = round(report.distance_m, 1)
    report.moving_s = round(report.moving_s, 1)
    return report


def _count(report: DailyReport, rec: LogRecord, tz: ZoneInfo) -> None:
    kind, d = rec.kind, rec.detail
    if kind == "tour.scheduled_start":
        report.tours_scheduled_started += 1
    elif kind == "tour.skipped":
        report.tours_skipped += 1
        report.skipped.append({"due": str(d.get("due", ""))[11:16] or _clock(rec, tz),
                               "tour": d.get("tour", ""), "reason": d.get("reason", "")})
    elif kind == "tour.stop":
        report.stops_visited += 1
    elif kind == "motion":
        report.distance_m += float(d.get("distance_m", 0.0))
        report.moving_s += float(d.get("moving_s", 0.0))
    elif kind == "help.requested":
        report.help_requests += 1
    elif kind == "help.resolved" and d.get("reason") != "preempted":
        report.help_waits_s.append(float(d.get("waited_s", 0.0)))
    elif kind in ("fault", "collision"):
        report.faults += kind == "fault"
        report.collisions += kind == "collision"
        report.fault_list.append({"time": _clock(rec, tz), "kind": kind,
                                  "what": d.get("name") or d.get("message") or "",
                                  "message": d.get("message", "")})
    elif kind == "estop.engaged":
        report.estops += 1
    if kind.startswith("operator."):
        report.operator_commands += 1


def format_report(r: DailyReport) -> str:
    """The report as text (``curio report --day``)."""
    wait = "-" if r.help_median_wait_s is None else f"{r.help_median_wait_s:g} s"
    lines = [
        f"Curio daily report for {r.day} ({r.timezone})",
        f"  tours run: {r.tours_started} (completed {r.tours_completed}, stopped "
        f"{r.tours_stopped}"
        + (f", interrupted by a restart {r.tours_interrupted}" if r.tours_interrupted else "")
        + ")",
        f"  scheduled: {r.tours_scheduled} (started {r.tours_scheduled_started}, skipped "
        f"{r.tours_skipped})",
        f"  stops visited: {r.stops_visited}",
        f"  distance driven: {r.distance_m:.1f} m; time moving: {r.moving_s / 60.0:.1f} min",
        f"  help requests: {r.help_requests}; median wait for help: {wait}",
        f"  faults: {r.faults}; collisions: {r.collisions}; e-stops: {r.estops}",
        f"  operator commands: {r.operator_commands}; records: {r.events}",
    ]
    if r.tours:
        lines.append("  tours:")
        for t in r.tours:
            stops = "" if t["stops_reached"] is None else f", {t['stops_reached']}/{t['stops']}" \
                " stops"
            why = f" ({t['reason']})" if t["reason"] else ""
            lines.append(f"    {t['time']} {t['tour']} [{t['source']}] {t['outcome']}{why}"
                         f"{stops}")
    if r.skipped:
        lines.append("  skipped:")
        lines += [f"    {s['due']} {s['tour']}: {s['reason']}" for s in r.skipped]
    if r.fault_list:
        lines.append("  faults:")
        lines += [f"    {f['time']} {f['kind']} {f['what']}" for f in r.fault_list]
    return "\n".join(lines) + "\n"
