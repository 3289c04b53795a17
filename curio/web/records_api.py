"""REST endpoints for the flight recorder's files and the replay's timeline, and their
:data:`ROUTES`.

**Recordings** (``<data_dir>/recordings``): the list says, per file, when it started (the
building's time), how long it lasts, how big it is and what happened — from the file's own
``/events`` and from the event log over the same span (tours, help requests, faults, e-stops,
collisions). A download needs ``data`` (operators): the page fetches it with its token; only a
plain ``.mcap`` name of a file directly in the directory is served.

**Replay.** The page never starts a replay on the rover: a replay re-runs the whole stack
(estimation, planning, control, the tree) beside the live one, on the rover's two or four
cores, while the rover may be guiding visitors — the live control loop and the safety stage
must not compete with it. The list gives the command to run on a laptop after downloading
(``curio replay FILE --web``), or on the rover over ssh while it is parked
(``GET /api/recordings`` → ``replay``). When the dashboard *is* served by ``curio replay
--web``, ``/api/replay`` is the timeline (:class:`~curio.record.timeline.ReplayTimeline`):
pause, play, speed and seek.

| method | path | needs | does |
|---|---|---|---|
| GET | ``/api/recordings`` | | the recordings, newest first, with what happened |
| GET | ``/api/recordings/{name}`` | data | download one (``application/octet-stream``) |
| GET | ``/api/replay`` | | ``{"active": false}``, or the timeline |
| POST | ``/api/replay`` ``{action: pause|play|seek|speed|finish, t_s?, speed?}`` | command | |
"""

from __future__ import annotations

import shlex
from collections import Counter
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

from aiohttp import web

from curio.core.errors import SetupError
from curio.eventlog.store import EventLog, LogQuery
from curio.record.library import list_recordings, resolve_download
from curio.web.apikit import building_zone, json_ok, local_time, present, read_body
from curio.web.inputs import http_error
from curio.web.services import GATE, SERVICES

__all__ = ["ROUTES", "happened"]

# Event-log kinds a recording's line mentions, with the words for one and for many.
TOLD = (("tour.started", "tour", "tours"), ("tour.skipped", "skipped tour", "skipped tours"),
        ("help.requested", "help request", "help requests"),
        ("collision", "collision", "collisions"), ("estop.engaged", "e-stop", "e-stops"),
        ("fault", "fault", "faults"))


def happened(log: EventLog, since_s: float, until_s: float) -> dict[str, Any]:
    """What the event log says happened between two UNIX times: counts and a sentence."""
    kinds = tuple(k for k, _, _ in TOLD)
    counts = Counter(r.kind for r in log.query(LogQuery(since_wall_s=since_s,
                                                        until_wall_s=until_s + 1.0,
                                                        kinds=kinds, limit=100_000)))
    words = [f"{counts[k]} {one if counts[k] == 1 else many}" for k, one, many in TOLD
             if counts[k]]
    return {"counts": dict(counts), "text": ", ".join(words) or "nothing notable logged"}


def _directory(request: web.Request) -> Path:
    return present(request.app[SERVICES].recordings_dir,
                   "the flight recorder is off (record.enabled = false in the config)")


def _listing(directory: Path, log: EventLog | None, tz: ZoneInfo) -> list[dict[str, Any]]:
    rows = []
    for i, info in enumerate(list_recordings(directory, scan=False)):
        row = info.as_dict()
        row["start_local"] = local_time(info.start_s, tz) if info.start_s else ""
        row["log"] = happened(log, info.start_s, info.start_s + info.duration_s) \
            if log is not None and info.start_s else None
        row["writing"] = i == 0 and not info.complete
        path = directory / info.name
        row["replay"] = {"laptop": f"curio replay {shlex.quote(info.name)} --web",
                         "rover": f"curio replay {shlex.quote(str(path))} --web "
                                  "--set web.port=8081"}
        rows.append(row)
    return rows


async def recordings(request: web.Request) -> web.Response:
    """The recordings, newest first (read off the loop: incomplete files are scanned)."""
    services = request.app[SERVICES]
    directory = _directory(request)
    rows = await services.clock.offload(_listing, directory, services.eventlog,
                                        building_zone(request))
    return json_ok({"recordings": rows, "directory": str(directory),
                    "replay_on_page": services.replay is not None})


async def download(request: web.Request) -> web.StreamResponse:
    """One recording as a file download (needs ``data``)."""
    request.app[GATE].require(request, "data")
    directory = _directory(request)
    name = request.match_info["name"]
    try:
        path = resolve_download(directory, name)
    except SetupError as exc:
        raise http_error(web.HTTPNotFound, str(exc)) from None
    return web.FileResponse(path, headers={
        "Content-Type": "application/octet-stream",
        "Content-Disposition": f'attachment; filename="{path.name}"'})


async def replay_status(request: web.Request) -> web.Response:
    """``{"active": false}`` on a live rover; the timeline under ``curio replay --web``."""
    timeline = request.app[SERVICES].replay
    return json_ok({"active": False} if timeline is None
                   else {"active": True, **timeline.status()})


def _seconds(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise http_error(web.HTTPBadRequest, f"{what} must be a number of seconds, got "
                                             f"{str(value)[:20]!r}")
    return float(value)


async def replay_control(request: web.Request) -> web.Response:
    """``{action: pause|play|seek|speed|finish, t_s?, speed?}`` → the timeline (202)."""
    request.app[GATE].require(request, "command")
    timeline = request.app[SERVICES].replay
    if timeline is None:
        raise http_error(web.HTTPConflict, "this is the live rover, not a replay: there is "
                                           "no timeline to control")
    body = await read_body(request)
    action = body.get("action")
    how = ""
    if action == "pause":
        timeline.pause()
    elif action == "play":
        timeline.play()
    elif action == "seek":
        how = timeline.seek(_seconds(body.get("t_s"), "t_s"))
    elif action == "speed":
        speed = body.get("speed")
        timeline.set_speed(None if speed in (None, "max") else _seconds(speed, "speed"))
    elif action == "finish":
        timeline.finish()
    else:
        raise http_error(web.HTTPBadRequest, f"unknown action {str(action)[:20]!r}; use "
                                             "pause, play, seek, speed or finish")
    return json_ok({"active": True, "seek": how, **timeline.status()}, status=202)


ROUTES: list[web.RouteDef] = [
    web.get("/api/recordings", recordings),
    web.get("/api/recordings/{name}", download),
    web.get("/api/replay", replay_status),
    web.post("/api/replay", replay_control),
]
