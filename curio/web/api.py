"""REST endpoints of the dashboard: module-level handlers and their route table, :data:`ROUTES`.

Reading (``GET``) is open. Every request that moves the rover or changes its data needs the
control token (:class:`~curio.web.auth.ControlGate`). Every rejection is JSON
``{"error": "<what was wrong and what is allowed>", "status": <code>}``: handlers raise
:func:`~curio.web.inputs.http_error`, and a :class:`~curio.web.inputs.CommandError` (invalid
input) or a path manager's ``PathError`` becomes ``400`` with its message in the server's
``json_errors`` middleware.

| method | path | does |
|---|---|---|
| GET | ``/api/state`` | the latched state snapshot (status, progress, help, paths, ...) |
| GET | ``/api/{map,costmap,local_costmap}.png?v=N`` | the grid as a PNG (immutable per version) |
| GET | ``/api/{map,costmap,local_costmap}.json`` | its version and geometry |
| GET | ``/api/tree``, ``/api/health``, ``/api/auth`` | tree snapshot, health panel, control? |
| GET | ``/api/paths`` | the paths |
| POST | ``/api/paths`` ``{name, waypoints?}`` | create a path |
| PATCH | ``/api/paths/{id}`` ``{name}`` | rename it |
| DELETE | ``/api/paths/{id}`` | delete it |
| POST | ``/api/paths/{id}/waypoints`` ``{x_m, y_m, yaw_rad?}`` | append a waypoint |
| DELETE | ``/api/paths/{id}/waypoints/{index}`` | remove a waypoint |
| POST | ``/api/command`` ``{action, path_id?, goal?, request_id?}`` | an operator command |
| POST | ``/api/initial_pose`` ``{x_m, y_m, yaw_rad}`` | set the pose in map |
"""

from __future__ import annotations

import asyncio
from typing import Any

from aiohttp import web

from curio.core.jsonable import to_json
from curio.web.encode import path_to_json
from curio.web.hub import Hub
from curio.web.inputs import (
    CommandError,
    describe_path_ids,
    http_error,
    parse_json_object,
    parse_pose,
)
from curio.web.services import GATE, HUB, ROVER
from curio.web.unattended_api import UNATTENDED_ROUTES

__all__ = ["ROUTES"]


# --- reading ----------------------------------------------------------------------------------


async def state(request: web.Request) -> web.Response:
    """The latched state snapshot, and whether this request may control the rover."""
    snapshot = request.app[HUB].snapshot()
    return web.json_response({**snapshot, "control": request.app[GATE].has_control(request)},
                             dumps=to_json)


async def auth(request: web.Request) -> web.Response:
    """Whether this request may control the rover, and whether a token is needed at all."""
    return web.json_response({"control": request.app[GATE].has_control(request),
                              "require_token": request.app[HUB].cfg.web.require_token})


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
    hub, paths = _paths_to_edit(request)
    body = await _body(request)
    name = body.get("name", "")
    if not isinstance(name, str):
        raise http_error(web.HTTPBadRequest, "'name' must be text")
    waypoints = _waypoints(body.get("waypoints", []))
    created = paths.create(name)
    for x, y, yaw in waypoints:
        paths.add_waypoint(created.id, x, y, yaw)
    return _path_changed(hub, paths, created.id, status=201)


async def rename_path(request: web.Request) -> web.Response:
    """``{name}`` → the renamed path."""
    hub, paths = _paths_to_edit(request)
    body = await _body(request)
    name = body.get("name")
    if not isinstance(name, str):
        raise http_error(web.HTTPBadRequest, "'name' (text) is required")
    pid = _existing_path_id(request, paths)
    paths.rename(pid, name)
    return _path_changed(hub, paths, pid)


async def delete_path(request: web.Request) -> web.Response:
    """Delete a path."""
    hub, paths = _paths_to_edit(request)
    pid = _existing_path_id(request, paths)
    paths.delete(pid)
    hub.paths_changed()
    return web.json_response({"deleted": pid})


async def add_waypoint(request: web.Request) -> web.Response:
    """``{x_m, y_m, yaw_rad?}`` (map) → the path with the waypoint appended (201)."""
    hub, paths = _paths_to_edit(request)
    body = await _body(request)
    pid = _existing_path_id(request, paths)
    pose = parse_pose(body)
    yaw = body.get("yaw_rad")
    paths.add_waypoint(pid, pose.x, pose.y, None if yaw is None else pose.yaw)
    return _path_changed(hub, paths, pid, status=201)


async def remove_waypoint(request: web.Request) -> web.Response:
    """The path without waypoint ``index``."""
    hub, paths = _paths_to_edit(request)
    pid = _existing_path_id(request, paths)
    index = _whole_number(request.match_info["index"], "waypoint index")
    paths.remove_waypoint(pid, index)
    return _path_changed(hub, paths, pid)


# --- moving the rover -------------------------------------------------------------------------


async def command(request: web.Request) -> web.Response:
    """``{action, path_id?, goal?, request_id?}`` → published (202), or a duplicate."""
    request.app[GATE].require_control(request)
    hub = request.app[HUB]
    body = await _body(request)
    cmd, published = request.app[ROVER].command(body)
    return web.json_response(
        {"ok": True, "request_id": cmd.request_id, "duplicate": not published,
         "action": cmd.action, "path_id": cmd.path_id,
         "status": hub.snapshot()["status"]},
        status=202, dumps=to_json)


async def initial_pose(request: web.Request) -> web.Response:
    """``{x_m, y_m, yaw_rad}`` (map) → published as the initial pose (202)."""
    request.app[GATE].require_control(request)
    body = await _body(request)
    pose = request.app[ROVER].initial_pose(body)
    return web.json_response({"ok": True, "pose": [pose.x, pose.y, pose.yaw]}, status=202)


# --- helpers ----------------------------------------------------------------------------------


async def _body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object ({} when the body is empty)."""
    raw = await request.read()
    if not raw:
        return {}
    return parse_json_object(raw)


def _paths_to_edit(request: web.Request) -> tuple[Hub, Any]:
    """Check control, then return the hub and the path manager (503 without one)."""
    request.app[GATE].require_control(request)
    hub = request.app[HUB]
    if hub.paths is None:
        raise http_error(web.HTTPServiceUnavailable,
                         "no path manager is running (the behaviour tree is not built)")
    return hub, hub.paths


def _whole_number(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise http_error(web.HTTPBadRequest,
                         f"{what} must be a whole number, got {text!r}") from None


def _existing_path_id(request: web.Request, paths: Any) -> int:
    """The ``{path_id}`` of the URL: 400 if it is not a number, 404 if there is no such path."""
    pid = _whole_number(request.match_info["path_id"], "path id")
    ids = [int(p.id) for p in paths.list_paths()]
    if pid not in ids:
        raise http_error(web.HTTPNotFound,
                         f"There is no path {pid}; paths are {describe_path_ids(ids)}")
    return pid


def _waypoints(raw_wps: Any) -> list[tuple[float, float, Any]]:
    """``[{x_m, y_m, yaw_rad?}, ...]`` → (x, y, yaw as sent) in map; 400 names the bad one."""
    if not isinstance(raw_wps, list):
        raise http_error(web.HTTPBadRequest,
                         "'waypoints' must be a list of {x_m, y_m, yaw_rad?}")
    wps = []
    for i, raw in enumerate(raw_wps):
        if not isinstance(raw, dict):
            raise http_error(web.HTTPBadRequest, f"waypoint {i} must be {{x_m, y_m, yaw_rad?}}")
        try:
            pose = parse_pose(raw)
        except CommandError as exc:
            raise http_error(web.HTTPBadRequest, f"waypoint {i}: {exc}") from None
        wps.append((pose.x, pose.y, raw.get("yaw_rad")))
    return wps


def _path_changed(hub: Hub, paths: Any, pid: int, status: int = 200) -> web.Response:
    """Tell the clients the paths changed; answer with path ``pid``."""
    hub.paths_changed()
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
    web.delete("/api/paths/{path_id}/waypoints/{index}", remove_waypoint),
    web.post("/api/command", command),
    web.post("/api/initial_pose", initial_pose),
    *UNATTENDED_ROUTES,  # issue 11: battery, dock, pose, zones, help (curio/web/unattended_api.py)
]
