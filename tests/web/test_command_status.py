"""``GET /api/commands/{request_id}``: a page that reconnected (or whose rover restarted)
learns what became of its command (found by ``curio soak``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.messages import Event
from curio.eventlog.commands import CommandJournal
from curio.robot import RobotModel
from curio.web.server import create_app
from curio.web.services import WebServices

from .conftest import ALICE, FakePaths, bearer, make_tokens


async def test_a_command_can_be_looked_up_after_it_was_answered(
        aiohttp_client: Any, cfg: Config, bus: Bus, tmp_path: Path) -> None:
    clock = SimClock()
    journal = CommandJournal(bus, clock, None)
    app = create_app(WebServices(cfg=cfg, clock=clock, bus=bus,
                                 tokens=make_tokens(tmp_path / "tokens.json"),
                                 robot=RobotModel.from_config(cfg.robot), paths=FakePaths(),
                                 journal=journal))
    client = await aiohttp_client(app)
    resp = await client.get("/api/commands/r-1")
    assert (await resp.json())["state"] == "unknown"
    resp = await client.post("/api/command", json={"action": "pause", "request_id": "r-1"},
                             headers=bearer(ALICE))
    assert resp.status == 202
    journal.poll()
    assert (await (await client.get("/api/commands/r-1")).json())["state"] == "pending"
    await journal.deliver(Event(clock.now(), "bt.command_accepted", {"request_id": "r-1",
                                                                     "message": "Paused."}))
    got = await (await client.get("/api/commands/r-1")).json()
    assert got["state"] == "answered" and got["answer"]["message"] == "Paused."
    assert got["action"] == "pause" and got["source"] == "web:alice"
    resp = await client.get("/api/commands/bad%20id")
    assert resp.status == 400 and "request id" in (await resp.json())["error"]
