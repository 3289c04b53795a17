"""REST and WebSocket endpoints for unattended operation (issue 11): battery, dock and home,
relocalising and setting the pose, zones, help and notifications.

These are the back-end services the dashboard's page calls (added to
:data:`curio.web.api.ROUTES`). Reading is open; every change needs a token whose role has the
permission it needs (``Gate.require``: ``command``, ``paths``, ``initial_pose``, ``zones``,
``data``). Errors are JSON ``{"error", "status"}``: a zone or a
pose that cannot be used is 400 with the sentence that says why.

* ``GET /api/power`` — ``/power``: voltage (filtered, raw), state of charge, time left, to low
  and to full, charging, level.
* ``GET /api/dock`` — the dock's state (``/dock``), home and staging poses, whether a dock is
  fitted; ``POST /api/dock`` — dock now (a ``go_home`` through the tree: with a dock, Go Home
  docks); ``POST /api/undock`` — back out of the dock.
* ``PUT /api/home`` ``{x_m, y_m, yaw_rad}`` — move home and the dock (path 0's last waypoint:
  also the next start pose).
* ``POST /api/relocalise`` — forget the pose and search the whole map (the tree turns in place,
  then resumes); ``POST /api/pose`` ``{x_m, y_m, yaw_rad, std_xy_m?, std_yaw_rad?}`` — set the
  pose on the map with its spread (default 0.25 m, 0.2 rad).
* ``GET /api/zones`` — ``{map, revision, zones}``; ``POST /api/zones`` ``{name, kind,
  polygon, speed_limit_mps?, revision?}`` (201); ``PATCH /api/zones/{id}`` (any of those);
  ``DELETE /api/zones/{id}?revision=N``; ``POST /api/zones/export`` — write the Nav2 filter
  masks beside the zone file, answer their paths.
* ``GET /api/help`` — ``/help``: the open request, its reason, since when, ``sound``;
  ``POST /api/notify/test`` — a test notification on every channel.
* ``GET /api/unattended/ws`` — a WebSocket that pushes ``{"t": "power" | "dock" | "help" |
  "zones" | "blockage", "msg": ...}`` as they change.
"""

from __future__ import annotations

import math
from typing import Any

from aiohttp import web

from curio.core.bus import Subscription, Topic
from curio.core.jsonable import to_json, to_jsonable
from curio.core.messages import OperatorCommand, PoseWithCovariance
from curio.core.topics import DOCK, HELP, HELP_BLOCKAGE, INITIAL_POSE, OPERATOR, POWER, ZONES
from curio.web.inputs import CommandError, http_error, parse_json_object, parse_pose
from curio.web.services import GATE, ROVER, SERVICES, UnattendedServices

__all__ = ["UNATTENDED_ROUTES", "UnattendedServices"]

GLOBAL_STD_XY_M = 1.0e3


def _services(request: web.Request) -> UnattendedServices:
    extra = request.app[SERVICES].unattended
    if extra is None:
        raise http_error(web.HTTPServiceUnavailable, "unattended operation is not wired in")
    return extra


async def _body(request: web.Request) -> dict[str, Any]:
    raw = await request.read()
    return parse_json_object(raw) if raw else {}


def _json(data: Any, status: int = 200) -> web.Response:
    return web.json_response(to_jsonable(data, 6), status=status, dumps=to_json)


# --- battery and dock -------------------------------------------------------------------------


async def power(request: web.Request) -> web.Response:
    """The battery as ``/power`` has it."""
    state = request.app[SERVICES].bus.latest(POWER)
    if state is None:
        raise http_error(web.HTTPNotFound, "no battery reading yet")
    return _json(state)


async def dock_state(request: web.Request) -> web.Response:
    """Dock state, home and staging poses."""
    extra = _services(request)
    bus = request.app[SERVICES].bus
    home = extra.home.to_json() if extra.home is not None else {}
    return _json({"enabled": extra.docker is not None, "state": bus.latest(DOCK), **home})


async def dock(request: web.Request) -> web.Response:
    """Dock now: Go Home through the tree (with a dock it docks)."""
    request.app[GATE].require(request, "command")
    extra = _services(request)
    if extra.docker is None:
        raise http_error(web.HTTPConflict, "there is no dock (dock.enabled = false); Go Home "
                                           "drives home instead")
    services = request.app[SERVICES]
    cmd = OperatorCommand(services.clock.now(), "go_home", source="web",
                          request_id=f"dock-{services.clock.now():.3f}")
    services.bus.publish(OPERATOR, cmd)
    return _json({"ok": True, "request_id": cmd.request_id}, status=202)


async def undock(request: web.Request) -> web.Response:
    """Back out of the dock."""
    request.app[GATE].require(request, "command")
    docker = _services(request).docker
    if docker is None or not docker.docked:
        raise http_error(web.HTTPConflict, "the rover is not on its dock")
    docker.undock()
    return _json({"ok": True, "state": docker.state}, status=202)


async def set_home(request: web.Request) -> web.Response:
    """Move home (and the dock) to ``{x_m, y_m, yaw_rad}``."""
    request.app[GATE].require(request, "paths")
    extra = _services(request)
    pose = parse_pose(await _body(request))
    if extra.placement is not None:
        problem = extra.placement(pose.x, pose.y)
        if problem:
            raise CommandError(f"home cannot be at ({pose.x:.2f}, {pose.y:.2f}): {problem}")
    extra.home.set(pose)
    return _json({"ok": True, **extra.home.to_json(),
                  "note": "the start pose after a restart; a simulated dock moves there at "
                          "the next start"})


# --- pose ---------------------------------------------------------------------------------------


def _publish_pose(request: web.Request, x: float, y: float, yaw: float, std_xy: float,
                  std_yaw: float) -> None:
    from curio.core.geometry import Pose2D

    services = request.app[SERVICES]
    services.bus.publish(INITIAL_POSE, PoseWithCovariance.from_std(
        services.clock.now(), Pose2D(x, y, yaw), std_xy, std_yaw))


async def relocalise(request: web.Request) -> web.Response:
    """Forget the pose and search the whole map."""
    request.app[GATE].require(request, "initial_pose")
    _publish_pose(request, 0.0, 0.0, 0.0, GLOBAL_STD_XY_M, math.pi)
    return _json({"ok": True, "message": "Searching the whole map."}, status=202)


def _std(body: dict[str, Any], key: str, default: float, low: float, high: float) -> float:
    value = body.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            low <= float(value) <= high):
        raise CommandError(f"{key} must be a number from {low:g} to {high:g}, got {value!r}")
    return float(value)


async def set_pose(request: web.Request) -> web.Response:
    """Set the pose on the map with its spread (refused off the map; every page is told who
    set it, as for ``/api/initial_pose``)."""
    who = request.app[GATE].require(request, "initial_pose")
    body = await _body(request)
    std_xy = _std(body, "std_xy_m", 0.25, 0.01, 10.0)
    std_yaw = _std(body, "std_yaw_rad", 0.2, 0.01, math.pi)
    pose = request.app[ROVER].initial_pose(body, who, (std_xy, std_yaw))
    return _json({"ok": True, "pose": [pose.x, pose.y, pose.yaw], "std_xy_m": std_xy,
                  "std_yaw_rad": std_yaw}, status=202)


# --- zones --------------------------------------------------------------------------------------


def _zones(request: web.Request) -> Any:
    zones = _services(request).zones
    if zones is None:
        raise http_error(web.HTTPServiceUnavailable, "zones are off (zones.enabled = false)")
    return zones


def _zone_id(request: web.Request) -> int:
    try:
        return int(request.match_info["zone_id"])
    except ValueError:
        raise CommandError(f"a zone id is a whole number, got "
                           f"{request.match_info['zone_id']!r}") from None


async def list_zones(request: web.Request) -> web.Response:
    """The zones of the map."""
    return _json(_zones(request).list_zones())


async def add_zone(request: web.Request) -> web.Response:
    """Add a zone."""
    who = request.app[GATE].require(request, "zones")
    zone = _zones(request).add(await _body(request), actor=who.name)
    return _json(zone.to_json(), status=201)


async def update_zone(request: web.Request) -> web.Response:
    """Change a zone."""
    who = request.app[GATE].require(request, "zones")
    zone = _zones(request).update(_zone_id(request), await _body(request), actor=who.name)
    return _json(zone.to_json())


async def delete_zone(request: web.Request) -> web.Response:
    """Delete a zone."""
    who = request.app[GATE].require(request, "zones")
    rev = request.query.get("revision")
    try:
        revision = int(rev) if rev is not None else None
    except ValueError:
        raise CommandError(f"revision must be a whole number, got {rev!r}") from None
    zid = _zone_id(request)
    _zones(request).delete(zid, revision, actor=who.name)
    return _json({"deleted": zid})


async def export_zones(request: web.Request) -> web.Response:
    """Write the Nav2 filter masks."""
    request.app[GATE].require(request, "data")
    files = await request.app[SERVICES].clock.offload(_zones(request).export)
    return _json({"ok": True, "files": [str(f) for f in files]})


# --- help ----------------------------------------------------------------------------------------


async def help_state(request: web.Request) -> web.Response:
    """The open help request."""
    return _json(request.app[SERVICES].bus.latest(HELP))


async def notify_test(request: web.Request) -> web.Response:
    """A test notification on every channel."""
    request.app[GATE].require(request, "command")
    desk = _services(request).help
    if desk is None:
        raise http_error(web.HTTPServiceUnavailable, "the help desk is not running")
    note = desk.test_notification()
    channels = [c.name for c in desk.notifier.channels]
    return _json({"ok": True, "channels": channels, "title": note.title,
                  "note": "sent in the background; notify.sent / notify.failed events follow"
                  if channels else "no channel is configured (help.webhook_urls, "
                                   "help.ntfy_urls)"}, status=202)


# --- WebSocket -------------------------------------------------------------------------------


async def stream(request: web.Request) -> web.StreamResponse:
    """Push ``power``, ``dock``, ``help``, ``zones`` and ``blockage`` as they change (the
    dashboard itself reads them from the hub's socket: :mod:`curio.web.unattended_frames`)."""
    gate = request.app[GATE]
    viewer = gate.identify(request).role == "viewer"
    remote = request.remote or "?"
    if viewer:  # counted with the dashboard's sockets without a token (503 over the caps)
        gate.open_viewer_socket(remote)
    try:
        return await _pump(request)
    finally:
        if viewer:
            gate.close_viewer_socket(remote)


async def _pump(request: web.Request) -> web.StreamResponse:
    """The socket's loop: the latest of each topic every 0.5 s."""
    services = request.app[SERVICES]
    bus = services.bus
    ws = web.WebSocketResponse(heartbeat=30.0)
    await ws.prepare(request)
    topics: dict[str, Topic[Any]] = {"power": POWER, "dock": DOCK, "help": HELP,
                                     "zones": ZONES, "blockage": HELP_BLOCKAGE}
    subs: dict[str, Subscription[Any]] = {name: bus.subscribe(topic)
                                          for name, topic in topics.items()}
    try:
        async for _ in services.clock.every(0.5):
            if ws.closed:
                break
            for name, sub in subs.items():
                msgs = sub.drain()
                if msgs:
                    await ws.send_str(to_json({"t": name, "msg": to_jsonable(msgs[-1], 6)}))
    except ConnectionResetError:  # the page went away between two updates
        pass
    finally:
        for sub in subs.values():
            sub.close()
        await ws.close()
    return ws


UNATTENDED_ROUTES: list[web.RouteDef] = [
    web.get("/api/power", power),
    web.get("/api/dock", dock_state),
    web.post("/api/dock", dock),
    web.post("/api/undock", undock),
    web.put("/api/home", set_home),
    web.post("/api/relocalise", relocalise),
    web.post("/api/pose", set_pose),
    web.get("/api/zones", list_zones),
    web.post("/api/zones", add_zone),
    web.post("/api/zones/export", export_zones),
    web.patch("/api/zones/{zone_id}", update_zone),
    web.delete("/api/zones/{zone_id}", delete_zone),
    web.get("/api/help", help_state),
    web.post("/api/notify/test", notify_test),
    web.get("/api/unattended/ws", stream),
]
