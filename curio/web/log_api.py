"""REST endpoints for the event log and the daily report (docs/tours.md): thin handlers over
``app.eventlog`` and :func:`~curio.eventlog.report.daily_report`, and their :data:`ROUTES`.

Reads open their own SQLite connection and block, so every one goes through
``clock.offload`` (a worker thread on the rover; inline on a simulated clock). Times people
type (``since``, ``until``, ``day``) are local to the building (``tours.timezone``): a date
``2025-06-02``, a time ``2025-06-02T10:30``, or UNIX seconds. Records come back with their
local time, so every page shows the building's time whatever the browser's zone.

| method | path | needs | does |
|---|---|---|---|
| GET | ``/api/events?since=&until=&kind=&source=&text=&limit=&offset=&order=`` | | records |
| GET | ``/api/events.csv?…`` (same filters) | data | the records as CSV, streamed |
| GET | ``/api/report?day=YYYY-MM-DD`` | | one day's report (default: today) |
| GET | ``/api/report/days?from=&to=`` | | one line per day for the plots (≤ 92 days) |

``kind`` is a comma-separated list of kinds (``tour.started``) or prefixes ending in ``.``
(``tour.``, ``operator.``).
"""

from __future__ import annotations

import datetime as dt
import io
from typing import Any
from zoneinfo import ZoneInfo

from aiohttp import web

from curio.eventlog.report import daily_report
from curio.eventlog.store import EventLog, LogQuery
from curio.web.apikit import building_zone, json_ok, local_time, present, whole_number
from curio.web.inputs import http_error
from curio.web.services import GATE, SERVICES

__all__ = ["ROUTES", "parse_local_time"]

MAX_PAGE = 1000
MAX_DAYS = 92
CSV_CHUNK = 2000
MAX_CSV_ROWS = 10_000_000
# Kinds the report's plots read, with what they count.
DAY_FIELDS = ("tours_started", "tours_completed", "tours_stopped", "tours_skipped",
              "tours_scheduled", "stops_visited", "help_requests", "help_median_wait_s",
              "distance_m", "moving_s", "faults", "collisions", "estops", "events")


def _log(request: web.Request) -> EventLog:
    return present(request.app[SERVICES].eventlog,
                   "the event log is off (eventlog.enabled = false in the config)")


def parse_local_time(text: str, tz: ZoneInfo, what: str) -> float:
    """``2025-06-02`` (local midnight), ``2025-06-02T10:30[:05]`` (local) or UNIX seconds →
    UNIX seconds; 400 naming ``what`` otherwise."""
    value = text.strip()
    try:
        return float(value) if value.replace(".", "", 1).isdigit() else \
            dt.datetime.fromisoformat(value).replace(tzinfo=tz).timestamp()
    except ValueError:
        raise http_error(web.HTTPBadRequest,
                         f"{what} {value[:30]!r} is not a time: use 2025-06-02, "
                         "2025-06-02T10:30 (the building's time) or UNIX seconds") from None


def _query(request: web.Request, limit_max: int, limit: str = "200") -> LogQuery:
    q = request.query
    tz = building_zone(request)
    since = parse_local_time(q["since"], tz, "since") if q.get("since") else None
    until = parse_local_time(q["until"], tz, "until") if q.get("until") else None
    kinds = tuple(k.strip() for k in q.get("kind", "").split(",") if k.strip())
    count = whole_number(q.get("limit", limit), "limit", low=1)
    return LogQuery(since_wall_s=since, until_wall_s=until, kinds=kinds,
                    source=q.get("source") or None, text=q.get("text") or None,
                    limit=min(count, limit_max),
                    offset=whole_number(q.get("offset", "0"), "offset", low=0),
                    newest_first=q.get("order", "newest") != "oldest")


def _page(log: EventLog, query: LogQuery, tz: ZoneInfo) -> dict[str, Any]:
    """One page of records with their local time, and how many match in all."""
    records = [{**r.to_json(), "local": local_time(r.wall_s, tz)} for r in log.query(query)]
    return {"records": records, "total": log.count(query), "offset": query.offset,
            "limit": query.limit, "timezone": tz.key}


async def events(request: web.Request) -> web.Response:
    """Records of the event log matching the filters, newest first by default."""
    log = _log(request)
    query = _query(request, MAX_PAGE)
    tz = building_zone(request)
    page = await request.app[SERVICES].clock.offload(_page, log, query, tz)
    return json_ok(page)


def _csv_chunk(log: EventLog, query: LogQuery, tz: ZoneInfo, first: bool) -> tuple[str, int]:
    out = io.StringIO()
    n = log.export_csv(out, query, tz)
    text = out.getvalue()
    return (text if first else text.split("\n", 1)[1]), n


async def events_csv(request: web.Request) -> web.StreamResponse:
    """The matching records as CSV (``id, time, wall_s, kind, source, detail``; time in the
    building's zone), oldest first, streamed in chunks (a whole year fits)."""
    request.app[GATE].require(request, "data")
    log = _log(request)
    query = _query(request, MAX_CSV_ROWS, str(MAX_CSV_ROWS))
    tz = building_zone(request)
    clock = request.app[SERVICES].clock
    name = f"curio-events-{dt.datetime.fromtimestamp(clock.wall_time(), tz):%Y%m%d-%H%M}.csv"
    response = web.StreamResponse(headers={
        "Content-Type": "text/csv; charset=utf-8",
        "Content-Disposition": f'attachment; filename="{name}"'})
    await response.prepare(request)
    total, offset, first = query.limit, query.offset, True
    while total > 0:
        chunk = LogQuery(query.since_wall_s, query.until_wall_s, query.kinds, query.source,
                         query.text, min(CSV_CHUNK, total), offset, newest_first=False)
        text, n = await clock.offload(_csv_chunk, log, chunk, tz, first)
        await response.write(text.encode("utf-8"))
        first = False
        if n < chunk.limit:
            break
        total -= n
        offset += n
    await response.write_eof()
    return response


def _day(request: web.Request, text: str | None, what: str) -> dt.date:
    if not text:
        tz = building_zone(request)
        return dt.datetime.fromtimestamp(request.app[SERVICES].clock.wall_time(), tz).date()
    try:
        return dt.date.fromisoformat(text.strip())
    except ValueError:
        raise http_error(web.HTTPBadRequest, f"{what} {text[:30]!r} is not a date; use "
                                             "YYYY-MM-DD, e.g. 2025-06-02") from None


async def report(request: web.Request) -> web.Response:
    """``?day=YYYY-MM-DD`` (default: today in the building) → that day's report."""
    log = _log(request)
    day = _day(request, request.query.get("day"), "day")
    tz = building_zone(request)
    rep = await request.app[SERVICES].clock.offload(daily_report, log, day, tz)
    return json_ok(rep.to_json())


def _days(log: EventLog, first: dt.date, last: dt.date, tz: ZoneInfo) -> list[dict[str, Any]]:
    out = []
    day = first
    while day <= last:
        rep = daily_report(log, day, tz).to_json()
        out.append({"day": rep["day"], **{k: rep[k] for k in DAY_FIELDS}})
        day += dt.timedelta(days=1)
    return out


async def report_days(request: web.Request) -> web.Response:
    """``?from=&to=`` (default: the 14 days up to today) → one line per day: tours started,
    completed, stopped, skipped, help requests and the median wait, distance, faults."""
    log = _log(request)
    last = _day(request, request.query.get("to"), "to")
    first = _day(request, request.query.get("from"), "from") if request.query.get("from") \
        else last - dt.timedelta(days=13)
    if first > last:
        raise http_error(web.HTTPBadRequest, f"'from' ({first}) is after 'to' ({last})")
    if (last - first).days >= MAX_DAYS:
        raise http_error(web.HTTPBadRequest, f"at most {MAX_DAYS} days at a time, asked for "
                                             f"{(last - first).days + 1}")
    tz = building_zone(request)
    days = await request.app[SERVICES].clock.offload(_days, log, first, last, tz)
    return json_ok({"days": days, "timezone": tz.key})


ROUTES: list[web.RouteDef] = [
    web.get("/api/events", events),
    web.get("/api/events.csv", events_csv),
    web.get("/api/report", report),
    web.get("/api/report/days", report_days),
]
