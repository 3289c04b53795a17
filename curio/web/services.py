"""What the dashboard's handlers find on the application, under typed keys.

:func:`curio.web.server.create_app` is given a :class:`WebServices` (the parts of the
application the dashboard uses: fakes in tests, the real parts from
:func:`curio.web.wiring.build_web`), builds the hub, the rover control and the control gate
from it, and stores them under these ``web.AppKey``s; every handler reads them from
``request.app``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from aiohttp import web

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.robot import RobotModel
from curio.web.auth import ControlGate
from curio.web.control import RoverControl
from curio.web.hub import Hub

__all__ = ["GATE", "HUB", "ROVER", "SERVICES", "STATIC_VERSION", "WebServices"]


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
        unattended: battery, dock, zones, help (``curio.web.unattended_api``), or None.
    """

    cfg: Config
    clock: Clock
    bus: Bus
    token: str
    robot: RobotModel
    paths: Any = None
    unattended: Any = None


SERVICES = web.AppKey("services", WebServices)
HUB = web.AppKey("hub", Hub)
ROVER = web.AppKey("rover", RoverControl)
GATE = web.AppKey("gate", ControlGate)
# A hash of the static files' names and times, appended to their URLs in the page.
STATIC_VERSION = web.AppKey("static_version", str)
