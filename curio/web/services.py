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
from typing import Any

from aiohttp import web

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.robot import RobotModel
from curio.web.auth import Gate
from curio.web.control import RoverControl
from curio.web.hub import Hub
from curio.web.tokens import TokenStore

__all__ = ["GATE", "HUB", "ROVER", "SERVICES", "STATIC_VERSION", "WebServices"]


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
        journal: the command journal (:class:`~curio.eventlog.commands.CommandJournal`):
            duplicates across restarts and ``GET /api/commands/{request_id}``; None: this
            run's duplicates only, and that endpoint answers ``unknown``.
    """

    cfg: Config
    clock: Clock
    bus: Bus
    tokens: TokenStore
    robot: RobotModel
    paths: Any = None
    part_states: Callable[[], dict[str, str]] | None = None
    journal: Any = None


SERVICES = web.AppKey("services", WebServices)
HUB = web.AppKey("hub", Hub)
ROVER = web.AppKey("rover", RoverControl)
GATE = web.AppKey("gate", Gate)
# A hash of the static files' names and times, appended to their URLs in the page.
STATIC_VERSION = web.AppKey("static_version", str)
