"""Web wiring: the dashboard server as a part of the application.

``build_web`` loads the named tokens (creating the admin token ``admin`` on the first start, or
migrating the single token of an older install; :mod:`curio.web.tokens`), builds the aiohttp
application and binds its listening socket at once, so the server's ``control_url`` — the
ready-to-open URL with the admin token, printed by ``curio run`` — is known before the app
starts (``web.port = 0`` picks a free port, for tests). Tokens are never written to the log.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from pathlib import Path

from aiohttp import web

from curio.bt.paths import PathManager
from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.errors import SetupError
from curio.core.parts import Part, Parts
from curio.eventlog.commands import CommandJournal
from curio.eventlog.store import EventLog
from curio.maps.control import MapsAccess
from curio.robot import RobotModel
from curio.tours.wiring import Tours
from curio.web.hub import Hub
from curio.web.server import SHUTDOWN_TIMEOUT_S, create_app
from curio.web.services import HUB, UnattendedServices, WebServices
from curio.web.tokens import TokenStore

__all__ = ["DashboardAddressError", "WebServer", "build_web", "open_tokens"]

log = logging.getLogger("curio.web")


class DashboardAddressError(SetupError, OSError):
    """The dashboard cannot listen on ``web.host:web.port`` (taken, or not a local address)."""


class WebServer:
    """The running dashboard: the aiohttp application on a socket bound at construction.

    Attributes:
        url: the page's URL without the token; ``control_url`` carries it.
        hub: the WebSocket hub (clients, latched state).
    """

    def __init__(self, services: WebServices) -> None:
        cfg = services.cfg.web
        self.services = services
        self.application = create_app(services)
        self.hub: Hub = self.application[HUB]
        family = socket.AF_INET6 if ":" in cfg.host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((cfg.host, cfg.port))
        except OSError as exc:
            self.sock.close()
            raise DashboardAddressError(
                f"the dashboard cannot listen on {cfg.host}:{cfg.port} ({exc.strerror}); "
                "set web.port to a free port (or 0 for any) or web.host to a local address"
            ) from exc
        self.sock.listen(128)
        self.sock.setblocking(False)
        self.port: int = self.sock.getsockname()[1]
        shown = "127.0.0.1" if cfg.host in ("0.0.0.0", "", "::") else cfg.host
        if ":" in shown:
            shown = f"[{shown}]"
        self.url = f"http://{shown}:{self.port}/"
        admin = services.tokens.first_admin()
        self.control_url = f"{self.url}?token={admin.token}" if admin is not None else self.url
        self._runner: web.AppRunner | None = None

    async def run(self) -> None:
        """Serve until cancelled."""
        self._runner = web.AppRunner(self.application, access_log=None, handle_signals=False,
                                     shutdown_timeout=SHUTDOWN_TIMEOUT_S)
        await self._runner.setup()
        site = web.SockSite(self._runner, self.sock)
        await site.start()
        cfg = self.services.cfg.web
        log.debug("dashboard: serving %s (control URL printed by the command)", self.url)
        if cfg.host in ("0.0.0.0", "::"):
            log.info("dashboard listens on all interfaces: http://%s:%d/ (the link with the "
                     "admin token is printed at start-up; 'curio token list' shows the tokens)",
                     socket.gethostname(), self.port)
        try:
            await asyncio.get_running_loop().create_future()
        finally:
            await self.close()

    async def close(self) -> None:
        """Close every client and the listening socket."""
        runner, self._runner = self._runner, None
        if runner is not None:
            await runner.cleanup()
        self.sock.close()


def open_tokens(cfg: Config, clock: Clock) -> TokenStore:
    """The named tokens of ``<data_dir>/web.tokens_file`` (an older install's single token
    migrated), with an admin token made on the first start."""
    tokens = TokenStore(cfg.data_path(cfg.web.tokens_file), cfg.data_path(cfg.web.token_file),
                        clock.wall_time)
    tokens.ensure_admin()
    return tokens


def build_web(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
              paths: PathManager, tokens: TokenStore,
              part_states: Callable[[], dict[str, str]] | None = None,
              tours: Tours | None = None, eventlog: EventLog | None = None,
              recordings_dir: Path | None = None,
              unattended: UnattendedServices | None = None,
              journal: CommandJournal | None = None,
              maps: MapsAccess | None = None) -> WebServer:
    """Construct the dashboard from ``cfg.web`` and register it as a part.

    Args:
        tokens: the named tokens (:func:`open_tokens`).
        part_states: the application's task states, for the health panel (optional).
        tours: the tours subsystem (tour authoring, schedules, the kiosk), or None.
        eventlog: the event log (the log view, the report, recordings' summaries), or None.
        recordings_dir: the flight recorder's directory (the recordings list), or None.
        unattended: battery, dock, zones, help (``curio/web/unattended_api.py``), or None.
        journal: the command journal (:class:`~curio.eventlog.commands.CommandJournal`).
        maps: the map library and its host (``/api/maps``, the ``/maps`` page), or None.
    """
    services = WebServices(cfg=cfg, clock=clock, bus=bus, tokens=tokens, robot=robot,
                           paths=paths, part_states=part_states, tours=tours,
                           eventlog=eventlog, recordings_dir=recordings_dir,
                           unattended=unattended, journal=journal, maps=maps)
    server = WebServer(services)
    parts.add(Part("web", run=server.run, close=server.close))
    return server
