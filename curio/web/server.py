"""The dashboard's aiohttp application: ``create_app(services) -> web.Application``.

Thin handlers over a :class:`~curio.web.hub.Hub`; everything the app needs comes in a
:class:`WebServices` (fakes in tests, the real parts from :func:`curio.web.wiring.build_web`).

Routes: ``/`` (the page), ``/static/...`` (hand-written JS and CSS, no CDN), ``/ws`` (the
WebSocket; ``?token=`` grants control), ``/api/...`` (REST, see :mod:`curio.web.api`).

WebSocket messages from the browser are JSON objects with an ``op``:

* ``{"op": "ping", "id"?}`` → ``{"t": "pong"}``
* ``{"op": "rate", "hz": N}`` → lower this client's stream rate (≤ ``web.client_rate_hz``)
* ``{"op": "teleop", "seq": n, "linear_mps": v, "angular_radps": w}`` (control)
* ``{"op": "command", "id"?, "action": ..., "path_id"?, "goal"?, "request_id"?}`` (control)
* ``{"op": "initial_pose", "x_m", "y_m", "yaw_rad"}`` (control)

Replies: ``{"t": "ack", "id", ...}`` or ``{"t": "error", "id", "code", "message"}``.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aiohttp import web

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.topics import HEALTH
from curio.robot import RobotModel
from curio.web.api import routes
from curio.web.auth import RateLimiter, check_origin, request_token, token_matches
from curio.web.control import RoverControl
from curio.web.hub import Hub
from curio.web.inputs import (
    http_error,
)
from curio.web.system import SystemMonitor, measure_loop_lag_ms

__all__ = ["HUB", "SERVICES", "WebServices", "create_app"]

log = logging.getLogger("curio.web")

STATIC_DIR = Path(__file__).resolve().parent / "static"


@dataclass
class WebServices:
    """What the dashboard uses from the application.

    Attributes:
        cfg: the whole configuration.
        clock: the injected clock.
        bus: the application bus.
        token: the control token (see :func:`curio.web.auth.load_or_create_token`).
        paths: the path manager, or None.
        robot: the robot model (footprint, home, laser pose, limits).
    """

    cfg: Config
    clock: Clock
    bus: Bus
    token: str
    robot: RobotModel
    paths: Any = None


HUB = web.AppKey("hub", Hub)
SERVICES = web.AppKey("services", WebServices)


def _static_version() -> str:
    digest = hashlib.sha1()
    for path in sorted(STATIC_DIR.glob("*")):
        if path.is_file():
            digest.update(path.name.encode())
            digest.update(str(path.stat().st_mtime_ns).encode())
    return digest.hexdigest()[:10]


def create_app(services: WebServices) -> web.Application:
    """Build the dashboard application (the hub starts and stops with it)."""
    cfg = services.cfg.web
    rover = RoverControl(services.cfg, services.clock, services.bus, services.paths)
    hub = Hub(services.cfg, services.robot, services.clock, services.bus, rover, services.paths)
    control_limiters: dict[str, RateLimiter] = {}

    @web.middleware
    async def errors(
        request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
    ) -> web.StreamResponse:
        length = request.content_length
        if length is not None and length > cfg.max_message_bytes:
            raise http_error(
                web.HTTPRequestEntityTooLarge,
                f"request body of {length} bytes exceeds web.max_message_bytes="
                f"{cfg.max_message_bytes}")
        try:
            return await handler(request)
        except web.HTTPException as exc:
            if exc.content_type == "application/json" or exc.status < 400:
                raise
            message = exc.text if exc.text and not exc.text.startswith(str(exc.status)) else (
                exc.reason or "error")
            if exc.status == 413:
                message = f"request body exceeds web.max_message_bytes={cfg.max_message_bytes}"
            elif exc.status == 404:
                message = f"there is no {request.path} on this rover"
            elif exc.status == 405:
                message = f"{request.method} is not allowed on {request.path}"
            raise http_error(type(exc), message) from None
        except ValueError as exc:  # PathError from the path manager, with its own message
            raise http_error(web.HTTPBadRequest, str(exc)) from None

    def require_control(request: web.Request) -> None:
        why = check_origin(request, cfg.allowed_origins)
        if why is not None:
            raise http_error(web.HTTPForbidden, why)
        if cfg.require_token:
            presented = request_token(request)
            if not presented:
                raise http_error(
                    web.HTTPUnauthorized,
                    "control needs the token: open the URL printed in the rover's start-up log "
                    "(http://…/?token=…) or send 'Authorization: Bearer <token>'")
            if not token_matches(presented, services.token):
                raise http_error(web.HTTPForbidden,
                                 "the token is wrong: use the URL from the rover's start-up log")
        if request.method != "GET":
            remote = request.remote or "?"
            limiter = control_limiters.setdefault(
                remote, RateLimiter(cfg.max_messages_per_s, burst=cfg.max_messages_per_s))
            if not limiter.allow(services.clock.now()):
                raise http_error(
                    web.HTTPTooManyRequests,
                    f"too many requests: at most {cfg.max_messages_per_s:g} per second")

    app = web.Application(middlewares=[errors], client_max_size=cfg.max_message_bytes)
    app[HUB] = hub
    app[SERVICES] = services
    version = _static_version()

    async def index(request: web.Request) -> web.Response:
        html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
        return web.Response(text=html.replace("{{VERSION}}", version), content_type="text/html",
                            headers={"Cache-Control": "no-cache"})

    async def websocket(request: web.Request) -> web.StreamResponse:
        why = check_origin(request, cfg.allowed_origins)
        if why is not None:
            raise http_error(web.HTTPForbidden, why)
        presented = request_token(request)
        control = not cfg.require_token or token_matches(presented, services.token)
        if presented and not control:
            raise http_error(web.HTTPForbidden,
                             "the token is wrong: use the URL from the rover's start-up log")
        ws = web.WebSocketResponse(max_msg_size=4 * cfg.max_message_bytes, heartbeat=20.0)
        await ws.prepare(request)
        client = hub.register(ws, control, request.remote or "")
        await client.serve(hub.unregister)
        return ws

    async def background(_: web.Application) -> AsyncIterator[None]:
        monitor = SystemMonitor()

        async def health_loop() -> None:
            due = services.clock.now()
            while True:
                due += 1.0
                await services.clock.sleep_until(due)
                hub.system = monitor.sample(await measure_loop_lag_ms())
                services.bus.publish(HEALTH, hub.own_health())
                hub.publish_health()

        hub.open()
        tasks = [asyncio.create_task(hub.run(), name="web.hub"),
                 asyncio.create_task(health_loop(), name="web.health"),
                 asyncio.create_task(rover.watch_teleop(), name="web.teleop_watchdog")]
        yield
        await hub.close()
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(BaseException):
                await task

    app.cleanup_ctx.append(background)
    app.router.add_get("/", index)
    app.router.add_get("/ws", websocket)
    app.router.add_routes(routes(HUB, require_control))
    app.router.add_static("/static", STATIC_DIR, append_version=False)
    return app
