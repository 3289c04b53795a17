"""The hub forwards the battery, the dock, the help request, the zones and what blocks the
rover as ``u:*`` frames on the dashboard's socket (a new page gets the latest at once)."""

from __future__ import annotations

import json
from typing import Any

from aiohttp import WSMsgType

from curio.core.messages import DockState, Event, HelpState, Obstacles, PowerState
from curio.core.topics import DOCK, HELP, HELP_BLOCKAGE, POWER, ZONES
from tests.web.conftest import MakeDash
from tests.web.test_hub import connect, spin


async def test_unattended_frames_reach_the_page(make_dash: MakeDash) -> None:
    d = await make_dash()
    d.bus.publish(POWER, PowerState(3.0, 7.31, 7.2, 0.45, 3600.0, 1200.0, None, False, "low"))
    d.bus.publish(DOCK, DockState(3.0, "approaching", 2))
    d.bus.publish(HELP, HelpState(3.0, True, "blocked", "My way is blocked.", 1.0, 0, True,
                                  (2.0, 1.0)))
    d.bus.publish(ZONES, Event(3.0, "zones", {"map": "m", "revision": 4, "zones": []}))
    d.bus.publish(HELP_BLOCKAGE, Obstacles(3.0, circles=((2.0, 1.0, 0.05),)))
    await spin()
    ws = await connect(d)
    frames: dict[str, Any] = {}
    while len(frames) < 5:
        msg = await ws.receive(timeout=5.0)
        if msg.type == WSMsgType.TEXT:
            data = json.loads(msg.data)
            if data["t"].startswith("u:"):
                frames[data["t"]] = data["msg"]
    assert (frames["u:power"]["soc"], frames["u:power"]["level"]) == (0.45, "low")
    assert (frames["u:dock"]["state"], frames["u:dock"]["attempt"]) == ("approaching", 2)
    assert frames["u:help"]["reason"] == "blocked" and frames["u:help"]["blocked_at"] == [2, 1]
    assert frames["u:zones"]["detail"]["revision"] == 4
    assert frames["u:blockage"]["circles"] == [[2, 1, 0.05]]
    await ws.close()
