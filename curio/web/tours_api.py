"""REST endpoints for tours, schedules and the running tour (docs/tours.md): thin handlers over
``app.tours.service`` and its stores, and their :data:`ROUTES`.

Every handler is one call of the service (or a store it holds). A
:class:`~curio.tours.model.TourError` is a ``ValueError``: the server's ``json_errors``
middleware answers it ``400 {"error": <its sentence>}``. Roles (:mod:`curio.web.tokens`):
reading is open (viewers see tours read-only); editing tours and schedules needs ``tours``
(operators, admins); starting and stopping a tour needs ``tour`` (operators and the kiosk
token). A kiosk may only start the tours offered at the kiosk (``kiosk: true``). Commands carry
the source ``web:<name>`` or ``kiosk:<name>``; edits name who made them in the event log
(``tours.changed``, ``schedules.changed``).

| method | path | needs | does |
|---|---|---|---|
| GET | ``/api/tours`` | | every tour (problems, estimate, route, schedules, running) |
| GET | ``/api/tours/{id}`` | | one tour, described |
| POST | ``/api/tours`` ``{name, stops?, kiosk?}`` | tours | create one (201) |
| PATCH | ``/api/tours/{id}`` ``{name?, kiosk?, revision?}`` | tours | rename; offer at the kiosk |
| POST | ``/api/tours/{id}/duplicate`` ``{name?}`` | tours | a copy (201; not at the kiosk) |
| DELETE | ``/api/tours/{id}?force=1`` | tours | delete (force: stop it, drop its schedules) |
| POST | ``/api/tours/{id}/stops`` ``{stop, index?, revision?}`` | tours | add a stop (201) |
| PATCH | ``/api/tours/{id}/stops/{i}`` ``{x_m?, …, revision?}`` | tours | change a stop |
| DELETE | ``/api/tours/{id}/stops/{i}?revision=`` | tours | remove a stop |
| POST | ``/api/tours/{id}/order`` ``{order}`` or ``{from, to}`` (+ revision) | tours | reorder |
| GET | ``/api/tours/{id}/estimate`` | | the estimated duration |
| POST | ``/api/place-check`` ``{x_m, y_m}`` | | can the rover stand there? |
| POST | ``/api/tours/{id}/start`` ``{request_id?}`` | tour | start it (202, the request id) |
| POST | ``/api/tours/stop`` | tour | stop the running tour (202) |
| GET | ``/api/tour`` | | the running tour (``/tour``) |
| GET | ``/api/schedules`` | | schedules, closed days, the building's zone and time |
| POST | ``/api/schedules`` ``{tour_id, days, times, enabled?, note?}`` | tours | add (201) |
| PATCH | ``/api/schedules/{id}`` | tours | change |
| DELETE | ``/api/schedules/{id}`` | tours | delete |
| PUT | ``/api/closed-days`` ``{dates, note?, closed?}`` | tours | close or reopen days |
| GET | ``/api/schedule/upcoming?count=&days=`` | | the next starts, and those waiting |
"""

from __future__ import annotations

from typing import Any

from aiohttp import web

from curio.core.jsonable import to_jsonable
from curio.core.topics import TOUR
from curio.tours.wiring import Tours
from curio.web.apikit import (
    building_zone,
    json_ok,
    local_time,
    optional_int,
    present,
    read_body,
    whole_number,
)
from curio.web.inputs import REQUEST_ID, http_error, parse_pose
from curio.web.services import GATE, SERVICES
from curio.web.tokens import Identity

__all__ = ["ROUTES", "tour_state_json"]

# Keys of a request body that are not fields of the thing edited.
_NOT_FIELDS = ("revision",)


def _tours(request: web.Request) -> Tours:
    return present(request.app[SERVICES].tours,
                   "tours are not available in this application (no tour store)")


def _editor(request: web.Request) -> tuple[Tours, Identity]:
    """The tours subsystem and who edits (needs ``tours``)."""
    who = request.app[GATE].require(request, "tours")
    return _tours(request), who


def _tour_id(request: web.Request) -> int:
    return whole_number(request.match_info["tour_id"], "tour number", low=1)


def _revision(body: dict[str, Any]) -> int | None:
    return optional_int(body.get("revision"), "revision")


def _flag(value: Any, what: str) -> bool:
    if not isinstance(value, bool):
        raise http_error(web.HTTPBadRequest, f"{what} must be true or false, got {value!r}")
    return value


def _described(tours: Tours, tour_id: int, status: int = 200) -> web.Response:
    return json_ok(tours.service.describe(tours.store.get(tour_id)), status=status)


# --- tours ------------------------------------------------------------------------------------


async def list_tours(request: web.Request) -> web.Response:
    """Every tour described, what runs, and what the editor needs for its live preview."""
    tours = _tours(request)
    cfg = request.app[SERVICES].cfg.tours
    service = tours.service
    return json_ok({
        "tours": service.list_tours(), "running": tour_state_json(request),
        "enabled": service.enabled, "home": [service.home.x, service.home.y],
        "estimate": {"speed_mps": cfg.estimate_speed_mps,
                     "detour_factor": cfg.estimate_detour_factor},
        "timezone": cfg.timezone,
    })


async def get_tour(request: web.Request) -> web.Response:
    """One tour, described."""
    return _described(_tours(request), _tour_id(request))


async def create_tour(request: web.Request) -> web.Response:
    """``{name, stops?, kiosk?}`` → the new tour (201)."""
    tours, who = _editor(request)
    body = await read_body(request)
    stops = body.get("stops", [])
    if not isinstance(stops, list):
        raise http_error(web.HTTPBadRequest, "'stops' must be a list of stops")
    tour = tours.service.create_tour(body.get("name"), stops,
                                     kiosk=_flag(body.get("kiosk", True), "'kiosk'"),
                                     actor=who.name)
    return _described(tours, tour.id, status=201)


async def patch_tour(request: web.Request) -> web.Response:
    """``{name?, kiosk?, revision?}`` → the renamed tour, offered at the kiosk or not."""
    tours, who = _editor(request)
    body = await read_body(request)
    tid, rev = _tour_id(request), _revision(body)
    unknown = sorted(set(body) - {"name", "kiosk", "revision"})
    if unknown or not {"name", "kiosk"} & set(body):
        raise http_error(web.HTTPBadRequest, "send 'name' (to rename) or 'kiosk' (true or "
                         "false: offered at the kiosk), with 'revision'"
                         + (f"; not {unknown[0]!r}" if unknown else ""))
    if "name" in body:
        rev = tours.store.rename(tid, body["name"], expect_revision=rev, actor=who.name).revision
    if "kiosk" in body:
        tours.store.set_kiosk(tid, body["kiosk"], expect_revision=rev, actor=who.name)
    return _described(tours, tid)


async def duplicate_tour(request: web.Request) -> web.Response:
    """``{name?}`` → a copy (201), not offered at the kiosk until an operator says so."""
    tours, who = _editor(request)
    body = await read_body(request)
    copy = tours.store.duplicate(_tour_id(request), body.get("name"), actor=who.name)
    return _described(tours, copy.id, status=201)


async def delete_tour(request: web.Request) -> web.Response:
    """Delete a tour; ``?force=1`` also stops it and removes its schedules."""
    tours, who = _editor(request)
    force = request.query.get("force", "") in ("1", "true", "yes")
    message = tours.service.delete_tour(_tour_id(request), force=force, actor=who.name)
    return json_ok({"deleted": _tour_id(request), "message": message})


async def add_stop(request: web.Request) -> web.Response:
    """``{stop: {name, x_m, y_m, yaw_rad?, dwell_s?, message?}, index?, revision?}`` → 201."""
    tours, who = _editor(request)
    body = await read_body(request)
    tid = _tour_id(request)
    tours.service.add_stop(tid, body.get("stop"), optional_int(body.get("index"), "index"),
                           expect_revision=_revision(body), actor=who.name)
    return _described(tours, tid, status=201)


async def update_stop(request: web.Request) -> web.Response:
    """``{x_m?, y_m?, yaw_rad?, name?, dwell_s?, message?, language?, voice?,
    route_path_id?, revision?}`` → the tour with stop ``i`` changed."""
    tours, who = _editor(request)
    body = await read_body(request)
    tid = _tour_id(request)
    index = whole_number(request.match_info["index"], "stop index")
    fields = {k: v for k, v in body.items() if k not in _NOT_FIELDS}
    tours.store.update_stop(tid, index, expect_revision=_revision(body), actor=who.name,
                            **fields)
    return _described(tours, tid)


async def remove_stop(request: web.Request) -> web.Response:
    """The tour without stop ``i`` (``?revision=`` guards against stale pages)."""
    tours, who = _editor(request)
    tid = _tour_id(request)
    tours.store.remove_stop(tid, whole_number(request.match_info["index"], "stop index"),
                            expect_revision=optional_int(request.query.get("revision"),
                                                         "revision", text=True),
                            actor=who.name)
    return _described(tours, tid)


async def reorder_stops(request: web.Request) -> web.Response:
    """``{order: [2, 0, 1], revision?}`` or ``{from, to, revision?}`` → the reordered tour."""
    tours, who = _editor(request)
    body = await read_body(request)
    tid, rev = _tour_id(request), _revision(body)
    if "order" in body:
        tours.store.reorder(tid, body["order"], expect_revision=rev, actor=who.name)
    elif "from" in body and "to" in body:
        tours.store.move_stop(tid, whole_number(body["from"], "'from'", text=False),
                              whole_number(body["to"], "'to'", text=False), expect_revision=rev,
                              actor=who.name)
    else:
        raise http_error(web.HTTPBadRequest, "send 'order' (every stop index once, in the new "
                                             "order) or 'from' and 'to' (move one stop)")
    return _described(tours, tid)


async def estimate(request: web.Request) -> web.Response:
    """The tour's estimated duration, home to home (straight legs × the detour factor)."""
    return json_ok(_tours(request).service.estimate(_tour_id(request)).to_json())


async def place_check(request: web.Request) -> web.Response:
    """``{x_m, y_m}`` (map) → ``{ok, problem}``: can the rover stand there (static map)?"""
    tours = _tours(request)
    pose = parse_pose(await read_body(request))
    problem = tours.placement(pose.x, pose.y)
    return json_ok({"ok": problem is None, "problem": problem})


# --- running tours ------------------------------------------------------------------------------


def _request_id(body: dict[str, Any]) -> str:
    rid = body.get("request_id", "")
    return rid if isinstance(rid, str) and REQUEST_ID.match(rid) else ""


async def start_tour(request: web.Request) -> web.Response:
    """Start tour ``id`` (202 with the request id the tree's answer carries). A kiosk may only
    start a tour offered at the kiosk."""
    who = request.app[GATE].require(request, "tour")
    tours = _tours(request)
    body = await read_body(request)
    tour = tours.store.get(_tour_id(request))
    if who.role == "kiosk" and not tour.kiosk:
        raise http_error(web.HTTPForbidden, f"the tour '{tour.name}' is not offered at the "
                                            "kiosk (an operator can offer it in Tours)")
    rid = tours.service.start_tour(tour.id, source=_channel(who), request_id=_request_id(body),
                                   actor=who.name)
    return json_ok({"ok": True, "request_id": rid, "tour_id": tour.id, "by": who.name},
                   status=202)


async def stop_tour(request: web.Request) -> web.Response:
    """Stop the running tour (202; 400 when none runs)."""
    who = request.app[GATE].require(request, "tour")
    rid = _tours(request).service.stop_tour(source=_channel(who), actor=who.name)
    return json_ok({"ok": True, "request_id": rid, "by": who.name}, status=202)


def _channel(who: Identity) -> str:
    """``web`` or ``kiosk``: the command's source is ``<channel>:<name>``."""
    return who.source.split(":", 1)[0]


def tour_state_json(request: web.Request) -> dict[str, Any] | None:
    """The latest ``/tour`` with its age in clock seconds (for "next stop in …"), or None."""
    services = request.app[SERVICES]
    state = services.bus.latest(TOUR)
    if state is None:
        return None
    return {**to_jsonable(state), "age_s": round(services.clock.now() - state.stamp, 3)}


async def running_tour(request: web.Request) -> web.Response:
    """The running tour, what the kiosk shows (``{"tour": null}`` before the tree said)."""
    return json_ok({"tour": tour_state_json(request)})


# --- schedules ----------------------------------------------------------------------------------


def _schedule_json(tours: Tours, sched: Any) -> dict[str, Any]:
    return {**sched.to_json(), "tour": tours.service.tour_name(sched.tour_id)}


def _clock_json(request: web.Request) -> dict[str, Any]:
    """The building's zone and its time now (the rover's clock)."""
    tz = building_zone(request)
    now = request.app[SERVICES].clock.wall_time()
    return {"timezone": tz.key, "now_wall_s": now, "now_local": local_time(now, tz)}


async def list_schedules(request: web.Request) -> web.Response:
    """Every schedule (with its tour's name), the closed days, the zone and the time now."""
    tours = _tours(request)
    return json_ok({"schedules": [_schedule_json(tours, s)
                                  for s in tours.schedules.list_schedules()],
                    "closed": [c.to_json() for c in tours.schedules.closed_days()],
                    **_clock_json(request)})


async def add_schedule(request: web.Request) -> web.Response:
    """``{tour_id, days, times, enabled?, note?}`` → the schedule (201); an overlap is 400
    with the day, both times and the earliest time that fits."""
    tours, who = _editor(request)
    body = await read_body(request)
    sched = tours.service.add_schedule(
        body.get("tour_id"), body.get("days"), body.get("times"),
        enabled=_flag(body.get("enabled", True), "'enabled'"), note=str(body.get("note", "")),
        actor=who.name)
    return json_ok(_schedule_json(tours, sched), status=201)


async def update_schedule(request: web.Request) -> web.Response:
    """``{tour_id?, days?, times?, enabled?, note?}`` → the changed schedule."""
    tours, who = _editor(request)
    body = await read_body(request)
    sid = whole_number(request.match_info["schedule_id"], "schedule number", low=1)
    if "enabled" in body:
        _flag(body["enabled"], "'enabled'")
    sched = tours.schedules.update(sid, actor=who.name, **body)
    return json_ok(_schedule_json(tours, sched))


async def delete_schedule(request: web.Request) -> web.Response:
    """Delete a schedule."""
    tours, who = _editor(request)
    sid = whole_number(request.match_info["schedule_id"], "schedule number", low=1)
    tours.schedules.delete(sid, actor=who.name)
    return json_ok({"deleted": sid})


async def closed_days(request: web.Request) -> web.Response:
    """``{dates: ["2025-12-25"], note?, closed?}`` → every closed day (closed false: reopen)."""
    tours, who = _editor(request)
    body = await read_body(request)
    dates = body.get("dates")
    if not isinstance(dates, list) or not dates:
        raise http_error(web.HTTPBadRequest, "'dates' must be a list of dates YYYY-MM-DD")
    days = tours.schedules.set_closed(dates, str(body.get("note", "")),
                                      closed=_flag(body.get("closed", True), "'closed'"),
                                      actor=who.name)
    return json_ok({"closed": [c.to_json() for c in days]})


async def upcoming(request: web.Request) -> web.Response:
    """``?count=10&days=7`` → the next scheduled starts (local time, tour names) and the
    starts the scheduler is still trying (with why they wait)."""
    tours = _tours(request)
    count = whole_number(request.query.get("count", "10"), "count", low=1)
    days = whole_number(request.query.get("days", "7"), "days", low=1)
    tz = building_zone(request)
    waiting = [{"schedule_id": d.occ.schedule_id, "tour_id": d.occ.tour_id,
                "tour": tours.service.tour_name(d.occ.tour_id),
                "local": d.occ.local.isoformat(), "reason": d.reason,
                "starting": bool(d.request_id),
                "until_local": local_time(d.deadline_wall_s, tz)}
               for d in tours.scheduler.pending]
    return json_ok({"upcoming": tours.service.upcoming(min(count, 100), min(days, 62)),
                    "waiting": waiting, **_clock_json(request)})


_TOUR = "/api/tours/{tour_id}"

ROUTES: list[web.RouteDef] = [
    web.get("/api/tours", list_tours),
    web.post("/api/tours", create_tour),
    web.post("/api/tours/stop", stop_tour),
    web.get(_TOUR, get_tour),
    web.patch(_TOUR, patch_tour),
    web.delete(_TOUR, delete_tour),
    web.post(f"{_TOUR}/duplicate", duplicate_tour),
    web.post(f"{_TOUR}/stops", add_stop),
    web.patch(f"{_TOUR}/stops/{{index}}", update_stop),
    web.delete(f"{_TOUR}/stops/{{index}}", remove_stop),
    web.post(f"{_TOUR}/order", reorder_stops),
    web.get(f"{_TOUR}/estimate", estimate),
    web.post(f"{_TOUR}/start", start_tour),
    web.post("/api/place-check", place_check),
    web.get("/api/tour", running_tour),
    web.get("/api/schedules", list_schedules),
    web.post("/api/schedules", add_schedule),
    web.patch("/api/schedules/{schedule_id}", update_schedule),
    web.delete("/api/schedules/{schedule_id}", delete_schedule),
    web.put("/api/closed-days", closed_days),
    web.get("/api/schedule/upcoming", upcoming),
]
