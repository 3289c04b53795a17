"""The fleet view in the dashboard's web stack, served by the fleet manager.

The page is ``curio/web/static/fleet.html`` with ``fleet.js`` and ``fleet.css``, built on the
dashboard's page kit (``pagekit.js``: the header, STOP, who you are; ``core.js``: the REST
client, messages, the confirm box; ``style.css`` and ``pages.css``), like ``/events`` or
``/recordings`` on a rover (``curio/web/pages.py``). The manager serves only the static files
the page needs, with a version (a hash of their names and times) in their URLs, and the two
endpoints the page kit asks for:

* ``GET /api/auth`` — who the browser is: with the manager's token an operator of the fleet
  (``command``, ``tour``, ``estop``), without one a viewer (the page is then view-only);
* ``POST /api/fleet/estop`` (the token) — a signed e-stop to every rover the manager knows;
  each rover latches it through its own safety stage and confirms in its status.
"""

from __future__ import annotations

import hashlib
import secrets
from pathlib import Path
from typing import Any

from aiohttp import web

from curio.web.pages import HEAD, STATIC_DIR

__all__ = ["FLEET_PERMISSIONS", "STATIC_FILES", "FleetPage"]

STATIC_FILES = ("style.css", "pages.css", "pagekit.js", "core.js", "fleet.js", "fleet.css")
FLEET_PERMISSIONS = ("command", "tour", "estop")
CONTENT_TYPES = {".css": "text/css", ".js": "text/javascript"}




def static_version() -> str:
    """A hash of the page's static files' names and modification times."""
    digest = hashlib.sha1()
    for name in STATIC_FILES:
        path = STATIC_DIR / name
        digest.update(name.encode())
        if path.is_file():
            digest.update(str(path.stat().st_mtime_ns).encode())
    return digest.hexdigest()[:10]


class FleetPage:
    """The fleet view's routes on the manager's web application.

    Args:
        manager: the fleet manager (``roster``, ``send``).
        token: the manager's control token.
    """

    def __init__(self, manager: Any, token: str) -> None:
        self.manager = manager
        self.token = token
        self.version = static_version()

    def add_routes(self, app: web.Application) -> None:
        """``/``, ``/static/<file>``, ``/api/auth``, ``/api/fleet/estop``."""
        app.router.add_get("/", self.page)
        app.router.add_get("/static/{name}", self.static)
        app.router.add_get("/api/auth", self.auth)
        app.router.add_post("/api/fleet/estop", self.estop)

    def operator(self, request: web.Request) -> bool:
        """Whether the request carries the manager's token."""
        header = request.headers.get("Authorization", "")
        given = header[7:].strip() if header.lower().startswith("bearer ") else ""
        return bool(given) and secrets.compare_digest(given.encode(), self.token.encode())

    async def page(self, request: web.Request) -> web.Response:
        """The fleet view."""
        # The dashboard pages' <head>, and the fleet view's own styles after it.
        html = (STATIC_DIR / "fleet.html").read_text(encoding="utf-8").replace("{{HEAD}}", HEAD)
        return web.Response(text=html.replace("{{VERSION}}", self.version),
                            content_type="text/html", headers={"Cache-Control": "no-cache"})

    async def static(self, request: web.Request) -> web.Response:
        """One of :data:`STATIC_FILES` (nothing else of the dashboard's directory)."""
        name = request.match_info["name"]
        if name not in STATIC_FILES:
            raise web.HTTPNotFound(text=f"no static file {name!r} on the fleet manager")
        body = (STATIC_DIR / name).read_bytes()
        return web.Response(body=body, content_type=CONTENT_TYPES[Path(name).suffix],
                            charset="utf-8", headers={"Cache-Control": "max-age=86400"})

    async def auth(self, request: web.Request) -> web.Response:
        """Who the browser is (the page kit's ``whoAmI``); a wrong token is refused."""
        if request.headers.get("Authorization") and not self.operator(request):
            return web.json_response({"error": "the token is wrong"}, status=403)
        if self.operator(request):
            who = {"name": "fleet", "role": "operator", "permissions": list(FLEET_PERMISSIONS)}
        else:
            who = {"name": "viewer", "role": "viewer", "permissions": []}
        return web.json_response({"who": who})

    async def estop(self, request: web.Request) -> web.Response:
        """A signed e-stop to every rover the manager knows (needs the token)."""
        if not self.operator(request):
            return web.json_response({"error": "the e-stop needs the fleet manager's token"},
                                     status=401)
        rovers = sorted(self.manager.roster.rovers)
        stamp = secrets.token_hex(4)
        for name in rovers:
            self.manager.send(name, {"action": "estop", "request_id": f"fleet-estop-{stamp}"})
        return web.json_response({"rovers": rovers})
