"""REST endpoints of the map library (issue 13, item 3; docs/maps.md), for the ``/maps`` page.

Reading is open; every change needs a token whose role has the ``maps`` permission (operators
and admins). A refusal is JSON ``{"error", "status"}`` with one sentence (400; 409 while the
rover is busy — a tour running, a switch under way; 503 where this App has no library or no
host to switch with).

* ``GET /api/maps`` — ``{active, maps: [{name, floor, revision, width_cells, height_cells,
  resolution_m, width_m, height_m, origin, has_world, source, created_wall_s, active,
  revisions}], state: {mapping, switching, pose_needed, message}}``.
* ``PATCH /api/maps/{name}`` ``{name?, floor?}`` — rename (not the active map), relabel.
* ``DELETE /api/maps/{name}`` — delete (never the active map).
* ``POST /api/maps/import`` — multipart ``name``, ``floor``, ``yaml`` (file), ``image``
  (file: PGM or PNG): a map_server map, validated by loading it as the rover would (201).
* ``GET /api/maps/{name}/cells`` — the grid for the editor (:func:`curio.maps.edits.grid_json`)
  with its ``revision``.
* ``POST /api/maps/{name}/cells`` ``{revision, changes: [[row, col, length, value], ...]}`` —
  save the edit as a new revision (the previous one kept); on the active map the App is
  rebuilt so the costmap and the localiser use it (202 then).
* ``POST /api/maps/{name}/restore`` ``{revision}`` — a kept revision becomes current again.
* ``POST /api/maps/active`` ``{name}`` — switch the active map (202; refused during a tour).
* ``POST /api/maps/mapping`` ``{action: start | save | discard, name?, floor?}`` — a mapping
  run from the page (202).
* ``GET /api/maps/live`` — the navigation map being used now (the one growing during a mapping
  run) as cells, its ``version`` and the rover's pose.
"""

from __future__ import annotations

from typing import Any

from aiohttp import BodyPartReader, web

from curio.core.topics import MAP, POSE
from curio.estimation.maps import OccupancyGrid
from curio.maps.control import MapControl, MapsAccess
from curio.maps.edits import apply_runs, grid_json
from curio.maps.library import MapLibraryError
from curio.web.apikit import json_ok, read_body, whole_number
from curio.web.inputs import http_error
from curio.web.services import GATE, SERVICES

__all__ = ["IMPORT_PATH", "ROUTES"]

IMPORT_PATH = "/api/maps/import"


def _maps(request: web.Request) -> MapsAccess:
    maps = request.app[SERVICES].maps
    if maps is None:
        raise http_error(web.HTTPServiceUnavailable, "this rover has no map library (it runs "
                                                     "one map: maps.enabled is false)")
    return maps


def _control(maps: MapsAccess) -> MapControl:
    if maps.control is None:
        raise http_error(web.HTTPServiceUnavailable, "switching, mapping and reloading maps "
                                                     "need `curio run` (this App has no host)")
    return maps.control


def _refused(exc: MapLibraryError) -> web.HTTPException:
    status = web.HTTPConflict if getattr(exc, "busy", False) else web.HTTPBadRequest
    return http_error(status, str(exc))


async def list_maps(request: web.Request) -> web.Response:
    """Every map, the active one, and what the host is doing."""
    maps = _maps(request)
    lib = maps.library
    out = []
    for name in lib.names():
        try:
            entry = lib.entry(name)
        except (MapLibraryError, ValueError) as exc:  # a damaged map is listed, not hidden
            out.append({"name": name, "error": str(exc), "active": name == maps.active})
            continue
        out.append({**entry.__dict__, "active": name == maps.active,
                    "revisions": lib.revisions(name)})
    state = maps.control.state() if maps.control is not None else {}
    return json_ok({"active": maps.active, "maps": out, "state": state,
                    "switching_available": maps.control is not None})


async def change_map(request: web.Request) -> web.Response:
    """Rename and/or relabel one map."""
    who = request.app[GATE].require(request, "maps")
    lib = _maps(request).library
    name = request.match_info["name"]
    body = await read_body(request)
    unknown = set(body) - {"name", "floor"}
    if unknown or not body:
        raise http_error(web.HTTPBadRequest, "send name and/or floor (nothing else), got "
                                             f"{sorted(body)}")
    try:
        if "floor" in body:
            lib.set_floor(name, body["floor"])
        if "name" in body:
            lib.rename(name, body["name"])
            name = body["name"]
        entry = lib.entry(name)
    except MapLibraryError as exc:
        raise _refused(exc) from None
    _publish(request, "maps.changed", {"map": name, "by": who.name})
    return json_ok({"ok": True, "map": entry.__dict__})


async def delete_map(request: web.Request) -> web.Response:
    """Delete one map (never the active one)."""
    who = request.app[GATE].require(request, "maps")
    maps = _maps(request)
    name = request.match_info["name"]
    try:
        if name == maps.active:
            raise MapLibraryError(f"map {name!r} is the active map and cannot be deleted: "
                                  "switch to another map first")
        maps.library.delete(name)
    except MapLibraryError as exc:
        raise _refused(exc) from None
    _publish(request, "maps.deleted", {"map": name, "by": who.name})
    return json_ok({"ok": True, "message": f"Map {name} deleted."})


async def import_map(request: web.Request) -> web.Response:
    """A map_server YAML + image uploaded as multipart form data."""
    who = request.app[GATE].require(request, "maps")
    lib = _maps(request).library
    limit = request.app[SERVICES].cfg.maps.max_upload_bytes
    fields = await _multipart(request, limit)
    for key in ("name", "yaml", "image"):
        if key not in fields:
            raise http_error(web.HTTPBadRequest, f"the upload has no {key!r} field: send name, "
                                                 "floor, yaml (file) and image (file)")
    try:
        entry = lib.import_files(fields["name"][1].decode("utf-8", "replace").strip(),
                                 fields["yaml"][1], fields["image"][0], fields["image"][1],
                                 fields.get("floor", ("", b""))[1].decode("utf-8", "replace"))
    except MapLibraryError as exc:
        raise _refused(exc) from None
    _publish(request, "maps.imported", {"map": entry.name, "by": who.name})
    return json_ok({"ok": True, "map": entry.__dict__}, status=201)


async def _multipart(request: web.Request, limit: int) -> dict[str, tuple[str, bytes]]:
    """The form's fields: name → (file name, bytes); refused beyond ``limit`` bytes."""
    if not request.content_type.startswith("multipart/"):
        raise http_error(web.HTTPBadRequest, "send the map as multipart/form-data (name, floor, "
                                             "yaml, image)")
    reader = await request.multipart()
    out: dict[str, tuple[str, bytes]] = {}
    total = 0
    while True:
        part = await reader.next()
        if part is None:
            break
        if not isinstance(part, BodyPartReader) or part.name is None or len(out) > 8:
            raise http_error(web.HTTPBadRequest, "the upload has an unexpected part")
        data = bytearray()
        while chunk := await part.read_chunk(65536):
            data += chunk
            total += len(chunk)
            if total > limit:
                raise http_error(web.HTTPRequestEntityTooLarge,
                                 f"the upload exceeds maps.max_upload_bytes={limit}")
        out[part.name] = (part.filename or "", bytes(data))
    return out


async def cells(request: web.Request) -> web.Response:
    """One map's grid for the editor."""
    lib = _maps(request).library
    name = request.match_info["name"]
    try:
        grid = lib.grid(name)
        revision = int(lib.meta(name).get("revision", 1))
    except MapLibraryError as exc:
        raise _refused(exc) from None
    return json_ok({"name": name, "revision": revision, **grid_json(grid)})


async def save_cells(request: web.Request) -> web.Response:
    """Save the editor's changes as a new revision (and use it now if the map is active)."""
    def edit(maps: MapsAccess, name: str, body: dict[str, Any]) -> tuple[int, dict[str, Any]]:
        expect = whole_number(body.get("revision"), "revision", low=1, text=False)
        grid, changed = apply_runs(maps.library.grid(name), body.get("changes"))
        revision = maps.library.save_revision(name, grid, expect_revision=expect)
        return revision, {"changed_cells": changed}

    return await _new_revision(request, "maps.edited", edit)


async def restore(request: web.Request) -> web.Response:
    """Make a kept revision current again (as a new revision)."""
    def back(maps: MapsAccess, name: str, body: dict[str, Any]) -> tuple[int, dict[str, Any]]:
        wanted = whole_number(body.get("revision"), "revision", low=1, text=False)
        return maps.library.restore(name, wanted), {"restored": wanted}

    return await _new_revision(request, "maps.restored", back)


async def _new_revision(request: web.Request, kind: str, make: Any) -> web.Response:
    """A new revision of ``{name}`` made by ``make(maps, name, body) -> (revision, extra)``;
    refused while the host is busy when the map is active (saving it rebuilds the App)."""
    who = request.app[GATE].require(request, "maps")
    maps = _maps(request)
    name = request.match_info["name"]
    body = await read_body(request)
    active = name == maps.active
    try:
        busy = maps.control.state().get("busy") if active and maps.control else None
        if busy:
            raise MapLibraryError(f"not saved: {busy}")
        revision, extra = make(maps, name, body)
    except MapLibraryError as exc:
        raise _refused(exc) from None
    _publish(request, kind, {"map": name, "revision": revision, "by": who.name, **extra})
    if "restored" in extra:
        text = f"Revision {extra['restored']} of {name} is current again (as revision {revision})."
    else:
        text = f"Saved {name} revision {revision} ({extra['changed_cells']} cells changed)."
    return await _maybe_reload(maps, active, who.name, text, {"revision": revision, **extra})


async def _maybe_reload(maps: MapsAccess, active: bool, actor: str, text: str,
                        extra: dict[str, Any]) -> web.Response:
    if active and maps.control is not None:
        text += " " + maps.control.reload(actor, "the active map was edited")
        return json_ok({"ok": True, "message": text, "reloading": True, **extra}, status=202)
    if active:
        text += " It is used from the next start."
    return json_ok({"ok": True, "message": text, "reloading": False, **extra})


async def switch(request: web.Request) -> web.Response:
    """Switch the active map (the page then asks for the pose on it)."""
    who = request.app[GATE].require(request, "maps")
    control = _control(_maps(request))
    body = await read_body(request)
    try:
        text = control.switch(body.get("name"), who.name)  # type: ignore[arg-type]
    except MapLibraryError as exc:
        raise _refused(exc) from None
    return json_ok({"ok": True, "message": text}, status=202)


async def mapping(request: web.Request) -> web.Response:
    """Start a mapping run, or end it (``save`` as a named map, or ``discard``)."""
    who = request.app[GATE].require(request, "maps")
    control = _control(_maps(request))
    body = await read_body(request)
    action = body.get("action")
    try:
        if action == "start":
            text = control.start_mapping(who.name)
        elif action in ("save", "discard"):
            text = control.finish_mapping(body.get("name", ""), body.get("floor", ""),
                                          who.name, save=action == "save")
        else:
            raise MapLibraryError(f"action {str(action)[:20]!r} is not allowed: start, save "
                                  "or discard")
    except MapLibraryError as exc:
        raise _refused(exc) from None
    return json_ok({"ok": True, "message": text}, status=202)


async def live(request: web.Request) -> web.Response:
    """The map in use now (growing during a mapping run), its version and the rover's pose."""
    bus = request.app[SERVICES].bus
    msg = bus.latest(MAP)
    if msg is None:
        raise http_error(web.HTTPNotFound, "no map has been published yet")
    grid = OccupancyGrid(msg.data, msg.resolution_m, msg.origin)
    pose = bus.latest(POSE)
    where = None if pose is None else [pose.pose.x, pose.pose.y, pose.pose.yaw]
    return json_ok({"version": msg.version, "pose": where, **grid_json(grid)})


def _publish(request: web.Request, kind: str, detail: dict[str, Any]) -> None:
    from curio.core.messages import Event
    from curio.core.topics import EVENTS

    services = request.app[SERVICES]
    services.bus.publish(EVENTS, Event(services.clock.now(), kind, detail))


ROUTES: list[web.RouteDef] = [
    web.get("/api/maps", list_maps),
    web.get("/api/maps/live", live),
    web.post(IMPORT_PATH, import_map),
    web.post("/api/maps/active", switch),
    web.post("/api/maps/mapping", mapping),
    web.patch("/api/maps/{name}", change_map),
    web.delete("/api/maps/{name}", delete_map),
    web.get("/api/maps/{name}/cells", cells),
    web.post("/api/maps/{name}/cells", save_cells),
    web.post("/api/maps/{name}/restore", restore),
]
