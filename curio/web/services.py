"""What the dashboard's handlers find on the application, under typed keys.

:func:`curio.web.server.create_app` is given a :class:`WebServices` (the parts of the
application the dashboard uses: fakes in tests, the real parts from
:func:`curio.web.wiring.build_web`), builds the hub, the rover control and the control gate
from it, and stores them under these ``web.AppKey``s; every handler reads them from
``request.app``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aiohttp import web

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.docking.docker import Docker
from curio.docking.home import HomeDock
from curio.eventlog.commands import CommandJournal
from curio.eventlog.store import EventLog
from curio.help.desk import HelpDesk
from curio.maps.control import MapsAccess
from curio.record.timeline import ReplayTimeline
from curio.robot import RobotModel
from curio.tours.placement import MapPlacement
from curio.tours.wiring import Tours
from curio.web.auth import Gate
from curio.web.control import RoverControl
from curio.web.hub import Hub
from curio.web.tokens import TokenStore
from curio.zones.service import ZoneService

__all__ = ["GATE", "HUB", "ROVER", "SERVICES", "STATIC_VERSION", "WebServices"]


@dataclass
class UnattendedServices:
    """The parts the unattended-operation endpoints use (``curio/web/unattended_api.py``).

    Attributes:
        home: the one home, which is also the dock.
        docker: the docking behaviour (None without a dock).
        zones: the zones of the active map (None when zones are off).
        help: the help desk.
        placement: the tours' map placement (where a new home may go).
    """

    home: HomeDock
    docker: Docker | None
    zones: ZoneService | None
    help: HelpDesk
    placement: MapPlacement


@dataclass
class WebServices:
    """What the dashboard uses from the application.

    Attributes:
        cfg: the whole configuration.
        clock: the injected clock.
        bus: the application bus.
        tokens: the named tokens (:class:`~curio.web.tokens.TokenStore`).
        paths: the path manager, or None.
        robot: the robot model (footprint, home, laser pose, limits).
        part_states: the application's task states for the health panel, or None.
        tours: the tours subsystem (stores, service, scheduler), or None.
        eventlog: the SQLite event log, or None (``eventlog.enabled`` off).
        recordings_dir: where the flight recorder writes its MCAP files, or None.
        replay: the replay's timeline when ``curio replay --web`` serves the page, or None.
        unattended: battery, dock, zones, help (``curio.web.unattended_api``), or None.
        journal: the command journal (:class:`~curio.eventlog.commands.CommandJournal`):
            duplicates across restarts and ``GET /api/commands/{request_id}``; None: this
            run's duplicates only, and that endpoint answers ``unknown``.
        maps: the map library and its host (:mod:`curio.web.maps_api`), or None.
    """

    cfg: Config
    clock: Clock
    bus: Bus
    tokens: TokenStore
    robot: RobotModel
    paths: Any = None
    part_states: Callable[[], dict[str, str]] | None = None
    tours: Tours | None = None
    eventlog: EventLog | None = None
    recordings_dir: Path | None = None
    replay: ReplayTimeline | None = None
    unattended: UnattendedServices | None = None
    journal: CommandJournal | None = None
    maps: MapsAccess | None = None


SERVICES = web.AppKey("services", WebServices)
HUB = web.AppKey("hub", Hub)
ROVER = web.AppKey("rover", RoverControl)
GATE = web.AppKey("gate", Gate)
# A hash of the static files' names and times, appended to their URLs in the page.
STATIC_VERSION = web.AppKey("static_version", str)
