"""REST endpoints of the dashboard and the validation shared with the WebSocket.

Reading (``GET``) is open. Every request that moves the rover or changes its data needs the
control token (see :mod:`curio.web.auth`). Every rejection is JSON
``{"error": "<what was wrong and what is allowed>", "status": <code>}``.

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

__all__ = ["routes"]


# --- handlers ---------------------------------------------------------------------------------


def routes(hub_key: web.AppKey[Hub], require_control: Any) -> list[web.RouteDef]:
    """The REST routes; ``require_control(request)`` raises when the token is missing/wrong."""

    def hub_of(request: web.Request) -> Hub:
        return request.app[hub_key]

    async def body_of(request: web.Request) -> dict[str, Any]:
        raw = await request.read()
        if not raw:
            return {}
        try:
            return parse_json_object(raw)
        except CommandError as exc:
            raise http_error(web.HTTPBadRequest, str(exc)) from None

    def paths_or_503(hub: Hub) -> Any:
        if hub.paths is None:
            raise http_error(web.HTTPServiceUnavailable,
                             "no path manager is running (the behaviour tree is not built)")
        return hub.paths

    def path_id_of(request: web.Request) -> int:
        text = request.match_info["path_id"]
        try:
            return int(text)
        except ValueError:
            raise http_error(web.HTTPBadRequest,
                             f"path id must be a whole number, got {text!r}") from None

    async def state(request: web.Request) -> web.Response:
        hub = hub_of(request)
        return web.json_response({**hub.snapshot(), "control": _has_control(request)},
                                 dumps=_dumps)

    def _has_control(request: web.Request) -> bool:
        try:
            require_control(request)
        except web.HTTPException:
            return False
        return True

    async def auth(request: web.Request) -> web.Response:
        return web.json_response({"control": _has_control(request),
                                  "require_token": hub_of(request).cfg.web.require_token})

    async def grid_png(request: web.Request) -> web.Response:
        hub = hub_of(request)
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
        hub = hub_of(request)
        name = request.match_info["name"]
        info = hub.grid_info(name)
        if info is None:
            raise http_error(web.HTTPNotFound, f"no {name} has been published yet")
        return web.json_response(info, dumps=_dumps)

    async def tree(request: web.Request) -> web.Response:
        return web.json_response(hub_of(request).tree_json(), dumps=_dumps)

    async def health(request: web.Request) -> web.Response:
        return web.json_response(hub_of(request).health_json(), dumps=_dumps)

    async def list_paths(request: web.Request) -> web.Response:
        return web.json_response(hub_of(request).paths_json(), dumps=_dumps)

    async def create_path(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        paths = paths_or_503(hub)
        body = await body_of(request)
        name = body.get("name", "")
        if not isinstance(name, str):
            raise http_error(web.HTTPBadRequest, "'name' must be text")
        raw_wps = body.get("waypoints", [])
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
        created = paths.create(name)
        for x, y, yaw in wps:
            paths.add_waypoint(created.id, x, y, yaw)
        created = paths.get(created.id)
        hub.paths_changed()
        return web.json_response(path_to_json(created), status=201, dumps=_dumps)

    async def rename_path(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        paths = paths_or_503(hub)
        body = await body_of(request)
        name = body.get("name")
        if not isinstance(name, str):
            raise http_error(web.HTTPBadRequest, "'name' (text) is required")
        pid = path_id_of(request)
        _must_exist(paths, pid)
        paths.rename(pid, name)
        hub.paths_changed()
        return web.json_response(path_to_json(paths.get(pid)), dumps=_dumps)

    async def delete_path(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        paths = paths_or_503(hub)
        pid = path_id_of(request)
        _must_exist(paths, pid)
        paths.delete(pid)
        hub.paths_changed()
        return web.json_response({"deleted": pid})

    async def add_waypoint(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        paths = paths_or_503(hub)
        body = await body_of(request)
        pid = path_id_of(request)
        _must_exist(paths, pid)
        try:
            pose = parse_pose(body)
        except CommandError as exc:
            raise http_error(web.HTTPBadRequest, str(exc)) from None
        yaw = body.get("yaw_rad")
        paths.add_waypoint(pid, pose.x, pose.y, None if yaw is None else pose.yaw)
        hub.paths_changed()
        return web.json_response(path_to_json(paths.get(pid)), status=201, dumps=_dumps)

    async def remove_waypoint(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        paths = paths_or_503(hub)
        pid = path_id_of(request)
        _must_exist(paths, pid)
        text = request.match_info["index"]
        try:
            index = int(text)
        except ValueError:
            raise http_error(web.HTTPBadRequest,
                             f"waypoint index must be a whole number, got {text!r}") from None
        paths.remove_waypoint(pid, index)
        hub.paths_changed()
        return web.json_response(path_to_json(paths.get(pid)), dumps=_dumps)

    async def command(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        body = await body_of(request)
        try:
            cmd, published = hub.rover.command(body)
        except CommandError as exc:
            raise http_error(web.HTTPBadRequest, str(exc)) from None
        return web.json_response(
            {"ok": True, "request_id": cmd.request_id, "duplicate": not published,
             "action": cmd.action, "path_id": cmd.path_id,
             "status": hub.snapshot()["status"]},
            status=202, dumps=_dumps)

    async def initial_pose(request: web.Request) -> web.Response:
        require_control(request)
        hub = hub_of(request)
        body = await body_of(request)
        try:
            pose = hub.rover.initial_pose(body)
        except CommandError as exc:
            raise http_error(web.HTTPBadRequest, str(exc)) from None
        return web.json_response({"ok": True, "pose": [pose.x, pose.y, pose.yaw]}, status=202)

    grid = "{name:map|costmap|local_costmap}"
    return [
        web.get("/api/state", state),
        web.get("/api/auth", auth),
        web.get(f"/api/{grid}.png", grid_png),
        web.get(f"/api/{grid}.json", grid_json),
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
    ]


def _must_exist(paths: Any, pid: int) -> None:
    ids = [int(p.id) for p in paths.list_paths()]
    if pid not in ids:
        raise http_error(web.HTTPNotFound,
                         f"There is no path {pid}; paths are {describe_path_ids(ids)}")


def _dumps(value: Any) -> str:
    return to_json(value)
