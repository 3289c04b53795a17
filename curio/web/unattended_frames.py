"""The dashboard's unattended-operation frames on the hub's WebSocket (issue 11).

The page reads the battery, the dock, the help request, the zones and what blocks the rover
from the same socket as everything else (so the socket caps, the Origin check and the page's
Offline state apply to them too). Each is a JSON text frame offered under its own stream key
(the latest wins, per client, at the client's rate; a new page gets the latest at once):

* ``{"t": "u:power", "msg": PowerState}`` from ``/power`` (volts, state of charge 0..1,
  seconds left, ``level``, ``charging``);
* ``{"t": "u:dock", "msg": DockState}`` from ``/dock`` (error in metres and degrees);
* ``{"t": "u:help", "msg": HelpState}`` from ``/help`` (``since_s`` and stamps in the rover's
  clock, seconds; ``blocked_at`` in ``map``, metres);
* ``{"t": "u:zones", "msg": Event}`` from ``/zones`` (``detail``: ``{map, revision, zones}``);
* ``{"t": "u:blockage", "msg": Obstacles}`` from ``/help_blockage`` (``map``, metres).

``GET /api/unattended/ws`` (:mod:`curio.web.unattended_api`) streams the same for other clients.
"""

from __future__ import annotations

from typing import Any

from curio.core.bus import Topic
from curio.core.jsonable import to_json, to_jsonable
from curio.core.topics import DOCK, HELP, HELP_BLOCKAGE, POWER, ZONES

__all__ = ["UNATTENDED_FRAMES", "unattended_frame"]

# Stream key (and frame type) → topic.
UNATTENDED_FRAMES: dict[str, Topic[Any]] = {
    "u:power": POWER, "u:dock": DOCK, "u:help": HELP, "u:zones": ZONES,
    "u:blockage": HELP_BLOCKAGE,
}


def unattended_frame(key: str, msg: Any) -> str:
    """The frame of type ``key`` carrying ``msg`` (floats to 6 significant digits)."""
    return to_json({"t": key, "msg": to_jsonable(msg, 6)})
