"""The dashboard's aiohttp application: ``create_app(services) -> web.Application``.

Thin module-level handlers over the services stored on the application
(:mod:`curio.web.services`); everything the app needs comes in a
:class:`~curio.web.services.WebServices` (fakes in tests, the real parts from
:func:`curio.web.wiring.build_web`).

Routes: ``/`` (the page), ``/static/...`` (hand-written JS and CSS, no CDN), ``/ws`` (the
WebSocket; a token as the subprotocol ``curio.token.<token>`` (next to ``curio.v1``), a header
or ``?token=`` names the operator; the messages are described in :mod:`curio.web.session`),
``/api/...`` (REST, see :mod:`curio.web.api`, :mod:`curio.web.tours_api`,
:mod:`curio.web.log_api`, :mod:`curio.web.records_api`, :mod:`curio.web.maps_api`), ``/kiosk``,
``/events``, ``/report``, ``/recordings``, ``/maps`` (:mod:`curio.web.pages`);
``/api/commands/{request_id}`` (:mod:`curio.web.answers`).

Every response carries security headers (:data:`SECURITY_HEADERS`: a Content-Security-Policy
with ``frame-ancestors 'none'``, ``nosniff``, ``Referrer-Policy: no-referrer``); every request
must name this rover in its ``Host`` (:meth:`curio.web.auth.Gate.check_host`); every error is
JSON ``{"error", "status"}`` with a sentence, never a traceback. WebSockets without a token are
capped per address and in total.

Shutdown is quick with pages open: ``on_shutdown`` closes every WebSocket (code 1001, so the
pages say "Offline" at once) before aiohttp waits for the handlers, and that wait is bounded by
:data:`SHUTDOWN_TIMEOUT_S`.

Background work runs in :func:`background`, the application's ``cleanup_ctx``: the hub's bus
pumps, the health panel (once a second, which also notices ``curio token`` changes and closes
the sockets of revoked tokens) and the teleop deadman start with the app and are cancelled when
it stops.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path

from aiohttp import web

from curio.core.topics import HEALTH
from curio.web import log_api, maps_api, pages, records_api, tours_api
from curio.web.answers import command_status
from curio.web.api import ROUTES
from curio.web.auth import WS_PROTOCOL, Gate, RedactTokens, check_origin, request_token
from curio.web.control import RoverControl
from curio.web.hub import Hub
from curio.web.inputs import CommandError, http_error
from curio.web.services import GATE, HUB, ROVER, SERVICES, STATIC_VERSION, WebServices
from curio.web.session import ClientSession
from curio.web.system import SystemMonitor, measure_loop_lag_ms

__all__ = ["CLOSE_TOKEN_REVOKED", "SECURITY_HEADERS", "SHUTDOWN_TIMEOUT_S", "background",
           "create_app", "index", "json_errors", "websocket"]

log = logging.getLogger("curio.web.server")

STATIC_DIR = Path(__file__).resolve().parent / "static"
# How long aiohttp may wait for request handlers when the server stops, seconds (wall).
SHUTDOWN_TIMEOUT_S = 1.0
# How long closing one WebSocket may wait for the browser's answer, seconds (wall).
WS_CLOSE_TIMEOUT_S = 0.5
# Custom WebSocket close code: the token was revoked or rotated.
CLOSE_TOKEN_REVOKED = 4001

CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
       "connect-src 'self'; media-src 'self' data: blob:; font-src 'self'; object-src 'none'; "
       "base-uri 'none'; form-action 'self'; frame-ancestors 'none'")
SECURITY_HEADERS = {
    "Content-Security-Policy": CSP,
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
    "Cross-Origin-Opener-Policy": "same-origin",
    "Cross-Origin-Resource-Policy": "same-origin",
    "Permissions-Policy": "camera=(), microphone=(), geolocation=()",
}
# aiohttp's loggers that may see a token (a refused WebSocket subprotocol, a request line).
AIOHTTP_LOGGERS = ("aiohttp.websocket", "aiohttp.server", "aiohttp.access", "aiohttp.web",
                   "aiohttp.internal")

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def create_app(services: WebServices) -> web.Application:
    """Build the dashboard application (the hub starts and stops with it)."""
    cfg = services.cfg.web
    rover = RoverControl(services.cfg, services.clock, services.bus, services.paths,
                         services.journal)
    app = web.Application(middlewares=[json_errors], client_max_size=cfg.max_message_bytes)
    app[SERVICES] = services
    app[ROVER] = rover
    app[HUB] = Hub(services.cfg, services.robot, services.clock, services.bus, rover,
                   services.paths, services.part_states)
    # Subscribed now, before the rover's parts start: what they say at their start (an unclean
    # restart, an interrupted tour, a file restored from its backup) reaches the pages too.
    app[HUB].open()
    app[GATE] = Gate(cfg, services.tokens, services.clock)
    app[STATIC_VERSION] = _static_version()
    app.on_response_prepare.append(_security_headers)
    app.on_shutdown.append(_close_sockets)
    app.cleanup_ctx.append(background)
    app.router.add_get("/", index)
    app.router.add_get("/ws", websocket)
    app.router.add_routes(ROUTES)
    for routes in (tours_api.ROUTES, log_api.ROUTES, records_api.ROUTES, maps_api.ROUTES,
                   pages.ROUTES):
        app.router.add_routes(routes)
    app.router.add_get("/api/commands/{request_id}", command_status)
    app.router.add_static("/static", STATIC_DIR, append_version=False)
    install_redaction(RedactTokens(services.tokens))
    return app


def install_redaction(redact: RedactTokens) -> None:
    """Scrub tokens from aiohttp's log records (replacing an earlier app's filter)."""
    for name in AIOHTTP_LOGGERS:
        logger = logging.getLogger(name)
        for old in [f for f in logger.filters if isinstance(f, RedactTokens)]:
            logger.removeFilter(old)
        logger.addFilter(redact)


@web.middleware
async def json_errors(request: web.Request, handler: Handler) -> web.StreamResponse:
    """The Host check, then every refusal as JSON ``{"error", "status"}`` with a sentence.

    A body over ``web.max_message_bytes`` is refused before the handler runs (a map upload
    has its own limit, ``maps.max_upload_bytes``); aiohttp's own
    404/405/413 get a sentence; a ``ValueError`` from a handler (a
    :class:`~curio.web.inputs.CommandError` for invalid input, a path manager's ``PathError``)
    becomes its status (400 unless it says otherwise) with its message; anything unexpected is
    logged and answered 500 without details.
    """
    request.app[GATE].check_host(request)
    max_bytes = request.app[SERVICES].cfg.web.max_message_bytes
    length = request.content_length
    if length is not None and length > max_bytes and request.path != maps_api.IMPORT_PATH:
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
        status = exc.status if isinstance(exc, CommandError) else 400
        raise http_error(_http_class(status), str(exc)) from None
    except (asyncio.CancelledError, ConnectionResetError):
        raise
    except Exception:
        log.exception("dashboard: %s %s failed", request.method, request.path)
        raise http_error(web.HTTPInternalServerError,
                         "the rover could not answer this request (the details are in its "
                         "log)") from None


def _http_class(status: int) -> type[web.HTTPException]:
    return {403: web.HTTPForbidden, 404: web.HTTPNotFound, 409: web.HTTPConflict,
            429: web.HTTPTooManyRequests}.get(status, web.HTTPBadRequest)


async def _security_headers(request: web.Request, response: web.StreamResponse) -> None:
    for key, value in SECURITY_HEADERS.items():
        response.headers.setdefault(key, value)
    if request.path.startswith("/api/") and "Cache-Control" not in response.headers:
        response.headers["Cache-Control"] = "no-store"


async def index(request: web.Request) -> web.Response:
    """The page, with the static files' version in their URLs."""
    html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
    return web.Response(text=html.replace("{{VERSION}}", request.app[STATIC_VERSION]),
                        content_type="text/html", headers={"Cache-Control": "no-cache"})


async def websocket(request: web.Request) -> web.StreamResponse:
    """One browser's WebSocket: a :class:`~curio.web.session.ClientSession` until it closes.

    The token (if any) names the operator; a wrong one is refused (403) before the upgrade, and
    sockets without a token are capped per address and in total (503).
    """
    gate = request.app[GATE]
    origin_problem = _origin_problem(request)
    if origin_problem is not None:
        raise http_error(web.HTTPForbidden, origin_problem)
    who = gate.identify(request)
    remote = request.remote or "?"
    viewer = who.role == "viewer"
    if viewer:
        gate.open_viewer_socket(remote)
    try:
        cfg = request.app[SERVICES].cfg.web
        ws = web.WebSocketResponse(max_msg_size=4 * cfg.max_message_bytes, heartbeat=10.0,
                                   protocols=(WS_PROTOCOL,), timeout=WS_CLOSE_TIMEOUT_S)
        await ws.prepare(request)
        hub = request.app[HUB]
        client = hub.register(ws, who, remote)
        presented = request_token(request)
        client.token_entry = gate.tokens.identify(presented) if presented else None
        await client.serve(hub.unregister)
    finally:
        if viewer:
            gate.close_viewer_socket(remote)
    return ws


def _origin_problem(request: web.Request) -> str | None:
    return check_origin(request, request.app[SERVICES].cfg.web.allowed_origins)


async def _close_sockets(app: web.Application) -> None:
    """``on_shutdown``: close every page's socket now, so the pages say Offline at once."""
    await app[HUB].close()


async def background(app: web.Application) -> AsyncIterator[None]:
    """The app's background tasks: the hub's pumps, the health loop, the teleop deadman."""
    hub = app[HUB]
    hub.open()
    tasks = [asyncio.create_task(hub.run(), name="web.hub"),
             asyncio.create_task(_health_loop(app), name="web.health"),
             asyncio.create_task(app[ROVER].watch_teleop(), name="web.teleop_watchdog")]
    yield
    await hub.close()
    for task in tasks:
        task.cancel()
    for task in tasks:
        with contextlib.suppress(BaseException):
            await task


async def _health_loop(app: web.Application) -> None:
    """Once a second: sample the system, publish the dashboard's health, refresh the panel,
    and close the sockets whose token was revoked or rotated."""
    hub, gate, services = app[HUB], app[GATE], app[SERVICES]
    monitor = SystemMonitor()
    async for _ in services.clock.every(1.0, phase_s=1.0):
        hub.system = monitor.sample(await measure_loop_lag_ms())
        hub.sample_rates()
        services.bus.publish(HEALTH, hub.own_health(
            wrong_tokens=float(gate.wrong.total),
            sockets_refused=float(gate.sockets_refused),
            rate_limited=float(gate.rate_limited)))
        hub.publish_health()
        if gate.tokens.reload_if_changed():
            await _drop_revoked(hub, gate)


async def _drop_revoked(hub: Hub, gate: Gate) -> None:
    valid = set(gate.tokens.entries())

    def revoked(client: ClientSession) -> bool:
        return client.token_entry is not None and client.token_entry not in valid

    closed = await hub.close_clients(revoked, CLOSE_TOKEN_REVOKED, b"token revoked or rotated")
    if closed:
        log.info("dashboard: closed %d page(s) whose token was revoked or rotated", closed)


def _static_version() -> str:
    digest = hashlib.sha1()
    for path in sorted(STATIC_DIR.glob("*")):
        if path.is_file():
            digest.update(path.name.encode())
            digest.update(str(path.stat().st_mtime_ns).encode())
    return digest.hexdigest()[:10]

