"""The dashboard's aiohttp application: ``create_app(services) -> web.Application``.

Thin module-level handlers over the services stored on the application
(:mod:`curio.web.services`); everything the app needs comes in a
:class:`~curio.web.services.WebServices` (fakes in tests, the real parts from
:func:`curio.web.wiring.build_web`).

Routes: ``/`` (the page), ``/static/...`` (hand-written JS and CSS, no CDN), ``/ws`` (the
WebSocket; ``?token=`` grants control; the messages are described in
:mod:`curio.web.session`), ``/api/...`` (REST, see :mod:`curio.web.api`).

Background work runs in :func:`background`, the application's ``cleanup_ctx``: the hub's bus
pumps, the health panel (once a second) and the teleop deadman start with the app and are
cancelled when it stops, after every client has been closed.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path

from aiohttp import web

from curio.core.topics import HEALTH
from curio.web.api import ROUTES
from curio.web.auth import ControlGate
from curio.web.control import RoverControl
from curio.web.hub import Hub
from curio.web.inputs import http_error
from curio.web.services import GATE, HUB, ROVER, SERVICES, STATIC_VERSION, WebServices
from curio.web.system import SystemMonitor, measure_loop_lag_ms

__all__ = ["background", "create_app", "index", "json_errors", "websocket"]

STATIC_DIR = Path(__file__).resolve().parent / "static"

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def create_app(services: WebServices) -> web.Application:
    """Build the dashboard application (the hub starts and stops with it)."""
    cfg = services.cfg.web
    rover = RoverControl(services.cfg, services.clock, services.bus, services.paths)
    app = web.Application(middlewares=[json_errors], client_max_size=cfg.max_message_bytes)
    app[SERVICES] = services
    app[ROVER] = rover
    app[HUB] = Hub(services.cfg, services.robot, services.clock, services.bus, rover,
                   services.paths)
    app[GATE] = ControlGate(cfg, services.token, services.clock)
    app[STATIC_VERSION] = _static_version()
    app.cleanup_ctx.append(background)
    app.router.add_get("/", index)
    app.router.add_get("/ws", websocket)
    app.router.add_routes(ROUTES)
    app.router.add_static("/static", STATIC_DIR, append_version=False)
    return app


@web.middleware
async def json_errors(request: web.Request, handler: Handler) -> web.StreamResponse:
    """Every refusal as JSON ``{"error", "status"}``, with a message that says what to do.

    A body over ``web.max_message_bytes`` is refused before the handler runs; aiohttp's own
    404/405/413 get a sentence; a ``ValueError`` from a handler (a
    :class:`~curio.web.inputs.CommandError` for invalid input, a path manager's ``PathError``)
    becomes 400 with its message.
    """
    max_bytes = request.app[SERVICES].cfg.web.max_message_bytes
    length = request.content_length
    if length is not None and length > max_bytes:
        raise http_error(
            web.HTTPRequestEntityTooLarge,
            f"request body of {length} bytes exceeds web.max_message_bytes={max_bytes}")
    try:
        return await handler(request)
    except web.HTTPException as exc:
        if exc.content_type == "application/json" or exc.status < 400:
            raise
        message = exc.text if exc.text and not exc.text.startswith(str(exc.status)) else (
            exc.reason or "error")
        if exc.status == 413:
            message = f"request body exceeds web.max_message_bytes={max_bytes}"
        elif exc.status == 404:
            message = f"there is no {request.path} on this rover"
        elif exc.status == 405:
            message = f"{request.method} is not allowed on {request.path}"
        raise http_error(type(exc), message) from None
    except ValueError as exc:  # CommandError, PathError: each with its own message
        raise http_error(web.HTTPBadRequest, str(exc)) from None


async def index(request: web.Request) -> web.Response:
    """The page, with the static files' version in their URLs."""
    html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
    return web.Response(text=html.replace("{{VERSION}}", request.app[STATIC_VERSION]),
                        content_type="text/html", headers={"Cache-Control": "no-cache"})


async def websocket(request: web.Request) -> web.StreamResponse:
    """One browser's WebSocket: a :class:`~curio.web.session.ClientSession` until it closes."""
    control = request.app[GATE].socket_control(request)
    cfg = request.app[SERVICES].cfg.web
    ws = web.WebSocketResponse(max_msg_size=4 * cfg.max_message_bytes, heartbeat=20.0)
    await ws.prepare(request)
    hub = request.app[HUB]
    client = hub.register(ws, control, request.remote or "")
    await client.serve(hub.unregister)
    return ws


async def background(app: web.Application) -> AsyncIterator[None]:
    """The app's background tasks: the hub's pumps, the health loop, the teleop deadman."""
    hub = app[HUB]
    hub.open()
    tasks = [asyncio.create_task(hub.run(), name="web.hub"),
             asyncio.create_task(_health_loop(hub, app[SERVICES]), name="web.health"),
             asyncio.create_task(app[ROVER].watch_teleop(), name="web.teleop_watchdog")]
    yield
    await hub.close()
    for task in tasks:
        task.cancel()
    for task in tasks:
        with contextlib.suppress(BaseException):
            await task


async def _health_loop(hub: Hub, services: WebServices) -> None:
    """Once a second: sample the system, publish the dashboard's health, refresh the panel."""
    monitor = SystemMonitor()
    async for _ in services.clock.every(1.0, phase_s=1.0):
        hub.system = monitor.sample(await measure_loop_lag_ms())
        services.bus.publish(HEALTH, hub.own_health())
        hub.publish_health()


def _static_version() -> str:
    digest = hashlib.sha1()
    for path in sorted(STATIC_DIR.glob("*")):
        if path.is_file():
            digest.update(path.name.encode())
            digest.update(str(path.stat().st_mtime_ns).encode())
    return digest.hexdigest()[:10]
