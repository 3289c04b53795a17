"""Damaged data files at start-up: replaced by their backup without loss, and told to the
operator (``data.restored`` / ``data.reset`` on the event log, ``/health`` ``data``) — found by
``curio soak``'s corrupt_file faults."""

from __future__ import annotations

import asyncio
from pathlib import Path

from curio.core.clock import SimClock
from curio.core.datanotes import DataNotes
from curio.core.topics import EVENTS, HEALTH, make_bus

from .test_schedules import store


def test_a_damaged_schedules_file_is_replaced_by_its_backup(tmp_path: Path) -> None:
    path = tmp_path / "schedules.json"
    first = store(path)
    first.add(1, ["mon"], ["10:00"])
    good = path.read_text()
    path.write_bytes(b"\x00" * 40)
    again = store(path)
    assert [s.times for s in again.list_schedules()] == [("10:00",)]
    assert again.restored is not None and "schedules.json.corrupt-1" in again.restored
    assert path.read_text() == good


async def test_notes_reach_the_event_log_and_health_then_clear() -> None:
    clock, bus = SimClock(), make_bus()
    events, health = bus.subscribe(EVENTS), bus.subscribe(HEALTH, maxsize=100)
    notes = DataNotes(bus, clock, recent_s=10.0)
    notes.restored("tours.json was replaced by its backup")
    notes.restored(None)
    task = asyncio.create_task(notes.run())
    await clock.advance(2.0)
    assert [(e.kind, e.detail["message"]) for e in events.drain()] == [
        ("data.restored", "tours.json was replaced by its backup")]
    last = health.drain()[-1]
    assert last.name == "data" and last.state == "degraded" and "tours.json" in last.message
    await clock.advance(10.0)
    assert health.drain()[-1].state == "ok"
    task.cancel()


def test_a_reset_is_an_error() -> None:
    notes = DataNotes(make_bus(), SimClock())
    notes.reset("paths.json and its backup could not be used: the configured paths are used")
    assert notes.health(1.0, 0.0).state == "error"
