"""The command journal: every operator command answered once, none replayed after a restart
(found by ``curio soak``: a page that reconnected, or whose rover was killed, could not learn
what became of its command; a command re-sent after a restart was carried out again, and one
the killed rover never answered stayed unanswered for ever)."""

from __future__ import annotations

from pathlib import Path

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.messages import Event, OperatorCommand
from curio.core.topics import EVENTS, OPERATOR, make_bus
from curio.eventlog.commands import RESTART_ANSWER, CommandJournal
from curio.eventlog.store import EventLog
from curio.web.control import RoverControl
from curio.web.tokens import Identity

T0 = 1_750_000_000.0


def test_this_runs_commands_are_pending_then_answered() -> None:
    clock, bus = SimClock(epoch_wall_s=T0), make_bus()
    journal = CommandJournal(bus, clock, None)
    assert journal.lookup("a")["state"] == "unknown"
    bus.publish(OPERATOR, OperatorCommand(0.0, "go_home", source="web:alice", request_id="a"))
    journal.poll()
    assert journal.lookup("a")["state"] == "pending" and journal.seen("a")
    bus.publish(EVENTS, Event(0.0, "bt.command_accepted", {"request_id": "a",
                                                           "message": "Going home."}))
    journal.poll()
    got = journal.lookup("a")
    assert got["state"] == "answered" and got["answer"]["message"] == "Going home."
    assert got["run"] == "this"


def _earlier_run(path: Path) -> None:
    log = EventLog(path)
    log.append("operator.go_home", {"request_id": "answered"}, wall_s=T0 - 60, source="web:a")
    log.append("bt.command_accepted", {"request_id": "answered", "message": "Going home."},
               wall_s=T0 - 59)
    log.append("operator.pause", {"request_id": "killed-first"}, wall_s=T0 - 30,
               source="web:b")
    log.append("operator.command", {"request_id": "activity-not-a-command"}, wall_s=T0 - 30)
    assert log.flush()
    log.close()


def test_after_a_restart_known_ids_are_duplicates_and_leftovers_are_answered(
        tmp_path: Path) -> None:
    _earlier_run(tmp_path / "events.sqlite3")
    log = EventLog(tmp_path / "events.sqlite3")
    clock, bus = SimClock(epoch_wall_s=T0), make_bus()
    events = bus.subscribe(EVENTS)
    journal = CommandJournal(bus, clock, log)
    assert journal.seen("answered") and journal.seen("killed-first")
    assert not journal.seen("activity-not-a-command")
    assert journal.lookup("answered")["answer"]["kind"] == "bt.command_accepted"
    assert journal.lookup("answered")["run"] == "earlier"
    assert journal.answer_earlier() == 1
    answers = [e for e in events.drain() if e.kind == "bt.command_rejected"]
    assert [e.detail["request_id"] for e in answers] == ["killed-first"]
    assert answers[0].detail["message"] == RESTART_ANSWER
    assert journal.lookup("killed-first")["state"] == "answered"
    assert journal.answer_earlier() == 0  # once
    log.close()


def test_a_command_sent_again_after_a_restart_is_not_carried_out_again(
        tmp_path: Path) -> None:
    _earlier_run(tmp_path / "events.sqlite3")
    log = EventLog(tmp_path / "events.sqlite3")
    clock, bus = SimClock(epoch_wall_s=T0), make_bus()
    ops = bus.subscribe(OPERATOR)
    rover = RoverControl(Config(), clock, bus, journal=CommandJournal(bus, clock, log))
    alice = Identity("alice", "operator")
    _, published = rover.command({"action": "go_home", "request_id": "answered"}, alice)
    assert not published and ops.drain() == []
    _, published = rover.command({"action": "go_home", "request_id": "new-one"}, alice)
    assert published and [c.request_id for c in ops.drain()] == ["new-one"]
    log.close()
