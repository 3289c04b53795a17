"""The fleet manager's web server: the fleet view (``/``, :mod:`curio.fleet.manager.page`: the
dashboard's page kit, every rover on the shared map with its state, battery, tour and alerts,
a link to each rover's own dashboard) and the JSON API.

Endpoints (JSON; changes need ``Authorization: Bearer <token>`` with the manager's token,
``<data_dir>/fleet_manager_token``, created 0600 on first start and printed at start-up):

* ``GET /api/fleet`` — rovers (state, battery and state of charge, dock, pose, tour, plan,
  alerts, dashboard address), jobs, tours, summary;
* ``GET /api/fleet/map`` — the shared map's size, resolution and origin; ``GET
  /api/fleet/map.png`` — the map as an image (row 0 at the top);
* ``POST /api/fleet/tours/{id}/dispatch`` — queue a run of a tour (``{"source"?}``);
* ``POST /api/fleet/rovers/{name}/command`` — a signed command to one rover
  (``{"action", ...}`` as in ``curio/fleet/commands.py``);
* ``GET /api/auth``, ``POST /api/fleet/estop`` — :mod:`curio.fleet.manager.page`.
"""

from __future__ import annotations

import io
import json
import logging
import secrets
from pathlib import Path
from typing import Any

import numpy as np
from aiohttp import web
from PIL import Image

from curio.core.fileio import atomic_write_text
from curio.fleet.commands import ACTIONS
from curio.fleet.manager.page import FleetPage
from curio.tours.model import TourError

__all__ = ["FleetWeb", "load_or_create_token"]

log = logging.getLogger("curio.fleet.web")
MAX_BODY = 64 * 1024


def load_or_create_token(path: Path) -> str:
    """The manager's control token (created, 0600, when missing)."""
    if path.is_file():
        token = path.read_text(encoding="utf-8").strip()
        if len(token) >= 16:
            return token
    token = secrets.token_urlsafe(24)
    atomic_write_text(path, token + "\n", private=True)
    return token


def _error(status: type[web.HTTPException], message: str) -> web.HTTPException:
    return status(text=json.dumps({"error": message}), content_type="application/json")


class FleetWeb:
    """The manager's HTTP server (see the module docstring).

    Args:
        manager: the :class:`~curio.fleet.manager.service.FleetManager`.
        host, port: where to listen.
        token: the control token.
    """

    def __init__(self, manager: Any, host: str, port: int, token: str) -> None:
        self.manager = manager
        self.host = host
        self.port = port
        self.token = token
        self._runner: web.AppRunner | None = None
        self.app = web.Application(client_max_size=MAX_BODY)
        self.page = FleetPage(manager, token)
        self.page.add_routes(self.app)
        self.app.router.add_get("/api/fleet", self._fleet)
        self.app.router.add_get("/api/fleet/map", self._map_meta)
        self.app.router.add_get("/api/fleet/map.png", self._map_png)
        self.app.router.add_post("/api/fleet/tours/{tour_id}/dispatch", self._dispatch)
        self.app.router.add_post("/api/fleet/rovers/{name}/command", self._command)

    async def start(self) -> None:
        """Listen (a busy port is a one-line setup error for the CLI)."""
        self._runner = web.AppRunner(self.app, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        try:
            await site.start()
        except OSError as exc:
            from curio.core.errors import SetupError

            raise SetupError(f"fleet.manager.port {self.port} on {self.host}: cannot listen "
                             f"({exc.strerror}); choose another port") from None

    async def stop(self) -> None:
        """Stop listening."""
        if self._runner is not None:
            await self._runner.cleanup()

    def _require(self, request: web.Request) -> None:
        header = request.headers.get("Authorization", "")
        given = header[7:].strip() if header.lower().startswith("bearer ") else ""
        if not given:
            raise _error(web.HTTPUnauthorized, "changes need 'Authorization: Bearer <token>' "
                         "(the token printed when curio fleet run started)")
        if not secrets.compare_digest(given.encode(), self.token.encode()):
            raise _error(web.HTTPForbidden, "the token is wrong")

    async def _body(self, request: web.Request) -> dict[str, Any]:
        try:
            body = await request.json() if request.can_read_body else {}
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise _error(web.HTTPBadRequest, "the body is not JSON") from None
        if not isinstance(body, dict):
            raise _error(web.HTTPBadRequest, "the body must be a JSON object")
        return body

    async def _fleet(self, request: web.Request) -> web.Response:
        m = self.manager
        return web.json_response({
            "rovers": m.rovers_json(), "jobs": [j.to_json() for j in m.dispatcher.jobs[-100:]],
            "tours": [{"id": t.id, "name": t.name, "stops": len(t.stops)}
                      for t in m.tours.list_tours()],
            "summary": m.summary(), "map": m.map_sha, "map_name": m.maps.map_name,
            "map_refused": dict(m.maps.refused),
            "zones": {"map": m.zones.map_name, "count": len(m.zones.zones),
                      "digest": m.zones.digest if m.zones.has_file else None}})

    async def _map_meta(self, request: web.Request) -> web.Response:
        g = self.manager.grid
        return web.json_response({"width": g.width, "height": g.height,
                                  "resolution_m": g.resolution_m,
                                  "origin": [g.origin.x, g.origin.y, g.origin.yaw]})

    async def _map_png(self, request: web.Request) -> web.Response:
        data = self.manager.grid.data
        img = np.full(data.shape, 205, dtype=np.uint8)
        img[data == 0] = 254
        img[data > 50] = 0
        buf = io.BytesIO()
        Image.fromarray(img[::-1]).save(buf, format="PNG")
        return web.Response(body=buf.getvalue(), content_type="image/png")

    async def _dispatch(self, request: web.Request) -> web.Response:
        self._require(request)
        body = await self._body(request)
        try:
            tour_id = int(request.match_info["tour_id"])
            job = self.manager.dispatch_tour(tour_id, str(body.get("source", "operator"))[:40])
        except (ValueError, TourError) as exc:
            raise _error(web.HTTPBadRequest, str(exc)) from None
        return web.json_response(job.to_json())

    async def _command(self, request: web.Request) -> web.Response:
        self._require(request)
        body = await self._body(request)
        name = request.match_info["name"]
        if name not in self.manager.roster.rovers:
            raise _error(web.HTTPNotFound, f"no rover called {name!r}")
        if body.get("action") not in ACTIONS:
            raise _error(web.HTTPBadRequest, f"action must be one of {', '.join(ACTIONS)}")
        self.manager.send(name, body)
        return web.json_response({"sent": True, "rover": name, "action": body["action"]})


