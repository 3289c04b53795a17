"""REST endpoints of the dashboard: module-level handlers and their route table, :data:`ROUTES`.

Reading (``GET``) is open. Every request that moves the rover or changes its data needs a token
whose role has the permission (:class:`~curio.web.auth.Gate`; roles in
:mod:`curio.web.tokens`). Every rejection is JSON ``{"error": "<what was wrong and what is
allowed>", "status": <code>}``: handlers raise :func:`~curio.web.inputs.http_error`, and a
:class:`~curio.web.inputs.CommandError` (invalid input) or a path manager's ``PathError``
becomes ``400`` (or the error's own status) with its message in the server's ``json_errors``
middleware. Waypoints and goals off the map are refused with the map's bounds.

A waypoint is appended, or inserted before ``index`` when it is given. Path edits may carry
``rev`` (from the path's JSON): when the path changed meanwhile the edit
is refused with 409 and says who changed it, instead of overwriting their change.

| method | path | needs | does |
|---|---|---|---|
| GET | ``/api/state`` | | the latched state snapshot (status, progress, e-stop log, ...) |
| GET | ``/api/{map,costmap,local_costmap}.png?v=N`` | | the grid as a PNG |
| GET | ``/api/{map,costmap,local_costmap}.json`` | | its version and geometry |
| GET | ``/api/tree``, ``/api/health``, ``/api/paths`` | | tree, health panel, paths |
| GET | ``/api/auth`` | | who this request is: name, role, permissions |
| POST | ``/api/estop`` ``{request_id?}`` | estop | engage the e-stop (never rate-limited) |
| POST | ``/api/command`` ``{action, path_id?, goal?, request_id?}`` | by action | a command |
| POST | ``/api/initial_pose`` ``{x_m, y_m, yaw_rad}`` | initial_pose | set the pose in map |
| POST | ``/api/paths`` ``{name, waypoints?}`` | paths | create a path |
| PATCH | ``/api/paths/{id}`` ``{name, rev?}`` | paths | rename it |
| DELETE | ``/api/paths/{id}`` | paths | delete it |
| POST | ``/api/paths/{id}/waypoints`` ``{x_m, y_m, yaw_rad?, index?, rev?}`` | paths | add |
| PUT | ``/api/paths/{id}/waypoints`` ``{waypoints, rev?}`` | paths | replace them all (reorder) |
| PATCH | ``/api/paths/{id}/waypoints/{index}`` ``{x_m, y_m, yaw_rad?, rev?}`` | paths | move one |
| DELETE | ``/api/paths/{id}/waypoints/{index}?rev=`` | paths | remove one |
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from typing import Any, NamedTuple

from aiohttp import web

from curio.core.jsonable import to_json
from curio.web.control import action_permission, map_bounds
from curio.web.encode import path_to_json
from curio.web.hub import Hub
from curio.web.inputs import (
    REQUEST_ID,
    CommandError,
    describe_path_ids,
    http_error,
    parse_json_object,
    parse_pose,
)
from curio.web.services import GATE, HUB, ROVER
from curio.web.tokens import Identity
from curio.web.unattended_api import UNATTENDED_ROUTES

__all__ = ["ROUTES"]


# --- reading ----------------------------------------------------------------------------------


async def state(request: web.Request) -> web.Response:
    """The latched state snapshot, and what this request may do."""
    snapshot = request.app[HUB].snapshot()
    who = request.app[GATE].peek(request)
    return web.json_response({**snapshot, "control": bool(who.permissions),
                              "who": _who_json(who)}, dumps=to_json)


async def auth(request: web.Request) -> web.Response:
    """Who this request is (a wrong token is refused with 403), and whether tokens are needed."""
    who = request.app[GATE].identify(request)
    return web.json_response({"control": bool(who.permissions), "who": _who_json(who),
                              "require_token": request.app[HUB].cfg.web.require_token})


def _who_json(who: Identity) -> dict[str, Any]:
    return {"name": who.name, "role": who.role, "permissions": sorted(who.permissions)}


async def grid_png(request: web.Request) -> web.Response:
    """A grid as a PNG; cached for ever when the URL names its current version."""
    hub = request.app[HUB]
    name = request.match_info["name"]
    # PNG encoding of a large grid takes milliseconds: keep it off the event loop.
    got = await asyncio.to_thread(hub.grid_png, name)
    if got is None:
        raise http_error(web.HTTPNotFound, f"no {name} has been published yet")
    png, version = got
    asked = request.query.get("v")
    cache = ("public, max-age=31536000, immutable" if asked == str(version)
             else "no-cache")
    return web.Response(body=png, content_type="image/png",
                        headers={"Cache-Control": cache, "X-Grid-Version": str(version)})


async def grid_json(request: web.Request) -> web.Response:
    """A grid's version and geometry."""
    name = request.match_info["name"]
    info = request.app[HUB].grid_info(name)
    if info is None:
        raise http_error(web.HTTPNotFound, f"no {name} has been published yet")
    return web.json_response(info, dumps=to_json)


async def tree(request: web.Request) -> web.Response:
    """The latest behaviour-tree snapshot."""
    return web.json_response(request.app[HUB].tree_json(), dumps=to_json)


async def health(request: web.Request) -> web.Response:
    """The health panel."""
    return web.json_response(request.app[HUB].health_json(), dumps=to_json)


async def list_paths(request: web.Request) -> web.Response:
    """The paths."""
    return web.json_response(request.app[HUB].paths_json(), dumps=to_json)


# --- editing paths ----------------------------------------------------------------------------


async def create_path(request: web.Request) -> web.Response:
    """``{name, waypoints?}`` → a new path (201)."""
    hub, paths, who = _paths_to_edit(request)
    body = await _body(request)
    name = body.get("name", "")
    if not isinstance(name, str):
        raise http_error(web.HTTPBadRequest, "'name' must be text")
    waypoints = _waypoints(body.get("waypoints", []), hub)
    with _editing(hub, who):
        created = paths.create(name)
        for x, y, yaw in waypoints:
            paths.add_waypoint(created.id, x, y, yaw)
        _activity(request, who, f"made path {created.id} “{created.name}”", created.id)
        return _path_changed(hub, paths, created.id, status=201)


async def rename_path(request: web.Request) -> web.Response:
    """``{name, rev?}`` → the renamed path."""
    hub, paths, who = _paths_to_edit(request)
    body = await _body(request)
    name = body.get("name")
    if not isinstance(name, str):
        raise http_error(web.HTTPBadRequest, "'name' (text) is required")
    pid = _existing_path_id(request, paths)
    old = _current(hub, paths, pid, body.get("rev"))
    with _editing(hub, who):
        paths.rename(pid, name)
        _activity(request, who,
                  f"renamed path {pid} “{old['name']}” to “{paths.get(pid).name}”", pid)
        return _path_changed(hub, paths, pid)


async def delete_path(request: web.Request) -> web.Response:
    """Delete a path."""
    hub, paths, who = _paths_to_edit(request)
    pid = _existing_path_id(request, paths)
    name = paths.get(pid).name
    with _editing(hub, who):
        paths.delete(pid)
        hub.paths_changed("deleted", pid)
    _activity(request, who, f"deleted path {pid} “{name}”", pid)
    return web.json_response({"deleted": pid})


async def add_waypoint(request: web.Request) -> web.Response:
    """``{x_m, y_m, yaw_rad?, index?, rev?}`` (map) → the path with the waypoint appended, or
    inserted before ``index`` (201)."""
    hub, paths, who = _paths_to_edit(request)
    body = await _body(request)
    pid = _existing_path_id(request, paths)
    current = _current(hub, paths, pid, body.get("rev"))
    (x, y, yaw), = _waypoints([body], hub, single=True)
    wps = _as_tuples(current)
    index = body.get("index")
    if index is None:
        index = len(wps)
    index = _index(index, len(wps) + 1, pid)
    wps.insert(index, (x, y, yaw))
    where = "at the end" if index == len(wps) - 1 else f"before waypoint {index + 2}"
    return _replace(request, hub, pid, wps, who,
                    f"added a waypoint to path {pid} {where}", status=201)


async def replace_waypoints(request: web.Request) -> web.Response:
    """``{waypoints: [{x_m, y_m, yaw_rad?}, ...], rev?}`` → the path with exactly these."""
    hub, paths, who = _paths_to_edit(request)
    body = await _body(request)
    pid = _existing_path_id(request, paths)
    _current(hub, paths, pid, body.get("rev"))
    if "waypoints" not in body:
        raise http_error(web.HTTPBadRequest, "'waypoints' (a list of {x_m, y_m, yaw_rad?}) "
                                             "is required")
    wps = _waypoints(body["waypoints"], hub)
    return _replace(request, hub, pid, wps, who, f"changed the waypoints of path {pid}")


async def move_waypoint(request: web.Request) -> web.Response:
    """``{x_m, y_m, yaw_rad?, rev?}`` → the path with waypoint ``index`` moved there."""
    hub, paths, who = _paths_to_edit(request)
    body = await _body(request)
    pid = _existing_path_id(request, paths)
    current = _current(hub, paths, pid, body.get("rev"))
    wps = _as_tuples(current)
    index = _index(request.match_info["index"], len(wps), pid)
    (x, y, yaw), = _waypoints([body], hub, single=True)
    wps[index] = (x, y, yaw if "yaw_rad" in body else wps[index][2])
    return _replace(request, hub, pid, wps, who, f"moved waypoint {index + 1} of path {pid}")


async def remove_waypoint(request: web.Request) -> web.Response:
    """The path without waypoint ``index`` (0-based; ``?rev=`` guards against stale pages)."""
    hub, paths, who = _paths_to_edit(request)
    pid = _existing_path_id(request, paths)
    current = _current(hub, paths, pid, request.query.get("rev"))
    index = _index(request.match_info["index"], len(current["waypoints"]), pid)
    with _editing(hub, who):
        paths.remove_waypoint(pid, index)
        _activity(request, who, f"removed waypoint {index + 1} of path {pid}", pid)
        return _path_changed(hub, paths, pid)


# --- moving the rover -------------------------------------------------------------------------


async def estop(request: web.Request) -> web.Response:
    """Engage the e-stop (202). Never rate-limited; no body needed. ``{"request_id"}`` (the
    one the page also sent over the WebSocket) makes a second copy a duplicate."""
    who = request.app[GATE].require(request, "estop")
    body = await _body(request)
    cmd = await request.app[ROVER].estop(who, _request_id(body.get("request_id")))
    return web.json_response({"ok": True, "action": "estop", "request_id": cmd.request_id,
                              "by": who.name}, status=202)


async def command(request: web.Request) -> web.Response:
    """``{action, path_id?, goal?, request_id?}`` → published (202), or a duplicate."""
    body = await _body(request)
    who = request.app[GATE].require(request, action_permission(body.get("action")))
    hub = request.app[HUB]
    cmd, published = await request.app[ROVER].command(body, who)
    return web.json_response(
        {"ok": True, "request_id": cmd.request_id, "duplicate": not published,
         "action": cmd.action, "path_id": cmd.path_id, "by": who.name,
         "status": hub.snapshot()["status"]},
        status=202, dumps=to_json)


async def initial_pose(request: web.Request) -> web.Response:
    """``{x_m, y_m, yaw_rad}`` (map) → published as the initial pose (202)."""
    who = request.app[GATE].require(request, "initial_pose")
    body = await _body(request)
    pose = request.app[ROVER].initial_pose(body, who)
    return web.json_response({"ok": True, "pose": [pose.x, pose.y, pose.yaw]}, status=202)


# --- helpers ----------------------------------------------------------------------------------


async def _body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object ({} when the body is empty)."""
    raw = await request.read()
    if not raw:
        return {}
    return parse_json_object(raw)


def _request_id(value: Any) -> str:
    """A request id as sent, or "" when it is not a short plain string."""
    return value if isinstance(value, str) and REQUEST_ID.match(value) else ""


def _paths_to_edit(request: web.Request) -> tuple[Hub, Any, Identity]:
    """Check the permission, then return the hub, the path manager (503 without one) and who."""
    who = request.app[GATE].require(request, "paths")
    hub = request.app[HUB]
    if hub.paths is None:
        raise http_error(web.HTTPServiceUnavailable,
                         "no path manager is running (the behaviour tree is not built)")
    return hub, hub.paths, who


@contextlib.contextmanager
def _editing(hub: Hub, who: Identity) -> Iterator[None]:
    """Name ``who`` in the paths broadcast the edit causes."""
    hub.path_editor = who.name
    try:
        yield
    finally:
        hub.path_editor = ""


def _activity(request: web.Request, who: Identity, what: str, path_id: int) -> None:
    request.app[ROVER].activity(who, "path", what, path_id=path_id)


def _whole_number(text: Any, what: str) -> int:
    if isinstance(text, bool):
        raise http_error(web.HTTPBadRequest, f"{what} must be a whole number, got {text!r}")
    try:
        return int(text)
    except (TypeError, ValueError):
        raise http_error(web.HTTPBadRequest,
                         f"{what} must be a whole number, got {str(text)[:20]!r}") from None


def _index(raw: Any, count: int, pid: int) -> int:
    """A waypoint index 0 … count-1 (negative numbers are refused, not counted from the end)."""
    index = _whole_number(raw, "waypoint index")
    if not 0 <= index < count:
        allowed = f"0 to {count - 1}" if count else "none (the path has no waypoints)"
        raise http_error(web.HTTPBadRequest,
                         f"path {pid} has no waypoint {index}; waypoint indexes are {allowed}")
    return index


def _existing_path_id(request: web.Request, paths: Any) -> int:
    """The ``{path_id}`` of the URL: 400 if it is not a number, 404 if there is no such path."""
    pid = _whole_number(request.match_info["path_id"], "path id")
    ids = [int(p.id) for p in paths.list_paths()]
    if pid not in ids:
        raise http_error(web.HTTPNotFound,
                         f"There is no path {pid}; paths are {describe_path_ids(ids)}")
    return pid


def _current(hub: Hub, paths: Any, pid: int, rev: Any) -> dict[str, Any]:
    """Path ``pid`` as JSON; 409 when ``rev`` is given and the path has changed since."""
    current = path_to_json(paths.get(pid))
    if rev is not None and rev != current["rev"]:
        by = hub.path_last_editor.get(pid)
        raise http_error(web.HTTPConflict,
                         f"path {pid} was changed{f' by {by}' if by else ''} while you were "
                         "editing; your change was not applied — the page shows the path as it "
                         "is now")
    return current


def _as_tuples(path_json: dict[str, Any]) -> list[tuple[float, float, Any]]:
    return [(w["x_m"], w["y_m"], w["yaw_rad"]) for w in path_json["waypoints"]]


class _Waypoint(NamedTuple):
    """A waypoint for the path manager (map, metres, radians or None)."""

    x_m: float
    y_m: float
    yaw_rad: float | None


def _replace(request: web.Request, hub: Hub, pid: int, wps: list[tuple[float, float, Any]],
             who: Identity, what: str, status: int = 200) -> web.Response:
    """Give path ``pid`` the waypoints ``wps``; tell every page who did ``what``."""
    with _editing(hub, who):
        hub.paths.replace_waypoints(pid, [_Waypoint(x, y, yaw) for x, y, yaw in wps])
        _activity(request, who, what, pid)
        return _path_changed(hub, hub.paths, pid, status=status)


def _waypoints(raw_wps: Any, hub: Hub, single: bool = False) -> list[tuple[float, float, Any]]:
    """``[{x_m, y_m, yaw_rad?}, ...]`` → (x, y, yaw) in map; 400 names the bad one, including
    one off the map (with the map's bounds)."""
    if not isinstance(raw_wps, list):
        raise http_error(web.HTTPBadRequest,
                         "'waypoints' must be a list of {x_m, y_m, yaw_rad?}")
    bounds = map_bounds(hub.bus)
    wps = []
    for i, raw in enumerate(raw_wps):
        what = "the waypoint" if single else f"waypoint {i}"
        if not isinstance(raw, dict):
            raise http_error(web.HTTPBadRequest, f"{what} must be {{x_m, y_m, yaw_rad?}}")
        try:
            pose = parse_pose(raw)
            if bounds is not None:
                bounds.require(pose.x, pose.y, what)
        except CommandError as exc:
            message = str(exc) if single or str(exc).startswith(what) else f"{what}: {exc}"
            raise http_error(web.HTTPBadRequest, message) from None
        wps.append((pose.x, pose.y, None if raw.get("yaw_rad") is None else pose.yaw))
    return wps


def _path_changed(hub: Hub, paths: Any, pid: int, status: int = 200) -> web.Response:
    """Tell the clients the paths changed; answer with path ``pid``."""
    hub.paths_changed("changed", pid)
    return web.json_response(path_to_json(paths.get(pid)), status=status, dumps=to_json)


_GRID = "{name:map|costmap|local_costmap}"

ROUTES: list[web.RouteDef] = [
    web.get("/api/state", state),
    web.get("/api/auth", auth),
    web.get(f"/api/{_GRID}.png", grid_png),
    web.get(f"/api/{_GRID}.json", grid_json),
    web.get("/api/tree", tree),
    web.get("/api/health", health),
    web.get("/api/paths", list_paths),
    web.post("/api/paths", create_path),
    web.patch("/api/paths/{path_id}", rename_path),
    web.delete("/api/paths/{path_id}", delete_path),
    web.post("/api/paths/{path_id}/waypoints", add_waypoint),
    web.put("/api/paths/{path_id}/waypoints", replace_waypoints),
    web.patch("/api/paths/{path_id}/waypoints/{index}", move_waypoint),
    web.delete("/api/paths/{path_id}/waypoints/{index}", remove_waypoint),
    web.post("/api/estop", estop),
    web.post("/api/command", command),
    web.post("/api/initial_pose", initial_pose),
    *UNATTENDED_ROUTES,  # issue 11: battery, dock, pose, zones, help (curio/web/unattended_api.py)
]
