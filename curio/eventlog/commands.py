"""The command journal: every operator command's fate, across reconnections and restarts.

Every command on ``/operator`` carries a ``request_id``, and the rover answers it once
(``bt.command_accepted`` / ``bt.command_rejected`` with that id). A page that lost its socket
may have missed the answer; after ``kill -9`` the new process knows nothing of the old one's
commands. :class:`CommandJournal` keeps the last ``size`` commands (action, source, time) and
their answers, from this run (the bus) and from earlier runs (the event log, where the event
recorder writes every command as ``operator.<action>`` and every answer), so that:

* a page can ask what became of a command (:meth:`CommandJournal.lookup`, served as
  ``GET /api/commands/{request_id}``): ``answered`` (with the answer), ``pending`` (published,
  not answered yet) or ``unknown`` (never received);
* a command sent again with a ``request_id`` the rover has already received — in this run or
  an earlier one — is not carried out a second time (:meth:`CommandJournal.seen`; the
  dashboard acknowledges it as a duplicate);
* the commands an earlier run received but never answered (it was killed first) get their
  answer at the next start: rejected, "the rover restarted before carrying this out; it is
  not resumed", so every command is answered once and none is replayed after a restart.

History is read once at construction (a blocking read of the event log); records older than
``history_s`` of wall time are not answered any more (nobody waits for them).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, get_args

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.messages import Event, OperatorAction, OperatorCommand
from curio.core.topics import EVENTS, OPERATOR

from .store import EventLog, LogQuery

__all__ = ["ANSWER_KINDS", "RESTART_ANSWER", "CommandJournal", "JournalEntry"]

log = logging.getLogger("curio.eventlog.commands")

POLL_S = 0.1
ANSWER_KINDS = ("bt.command_accepted", "bt.command_rejected")
ACTIONS = frozenset(get_args(OperatorAction))
RESTART_ANSWER = ("Not carried out: the rover restarted before answering this command, and "
                  "nothing is resumed after a restart; send it again if you still want it.")


@dataclass
class JournalEntry:
    """One command and its answer.

    Attributes:
        request_id, action, source: as sent.
        wall_s: when it was published (UNIX seconds).
        earlier: it was received by an earlier run of Curio.
        answer: ``{kind, message, wall_s}`` once answered.
    """

    request_id: str
    action: str
    source: str
    wall_s: float
    earlier: bool = False
    answer: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """``{request_id, state, action, source, wall_s, run, answer}``."""
        return {"request_id": self.request_id,
                "state": "answered" if self.answer is not None else "pending",
                "action": self.action, "source": self.source, "wall_s": self.wall_s,
                "run": "earlier" if self.earlier else "this", "answer": self.answer}


class CommandJournal:
    """The journal (see the module docstring).

    Args:
        bus, clock: the application's.
        eventlog: the event log (None: this run only).
        size: commands remembered.
        history_s: earlier runs' commands younger than this (wall seconds) are loaded.
    """

    def __init__(self, bus: Bus, clock: Clock, eventlog: EventLog | None, size: int = 5000,
                 history_s: float = 86400.0) -> None:
        self.bus = bus
        self.clock = clock
        self.size = size
        self.history_s = history_s
        self.entries: OrderedDict[str, JournalEntry] = OrderedDict()
        self.unanswered_earlier: list[JournalEntry] = []
        self._ops = bus.subscribe(OPERATOR)
        self._events = bus.subscribe(EVENTS)
        if eventlog is not None:
            self._load(eventlog)

    # --- history ------------------------------------------------------------------------------

    def _load(self, eventlog: EventLog) -> None:
        since = self.clock.wall_time() - self.history_s
        try:
            records = eventlog.query(LogQuery(
                since_wall_s=since, kinds=("operator.", *ANSWER_KINDS), limit=4 * self.size,
                newest_first=True))
        except Exception as exc:  # an unreadable log must not stop the rover
            log.warning("the command journal starts empty: %s", exc)
            return
        answers: dict[str, dict[str, Any]] = {}
        for rec in records:
            rid = str(rec.detail.get("request_id") or "")
            if not rid:
                continue
            if rec.kind in ANSWER_KINDS:
                answers.setdefault(rid, {"kind": rec.kind,
                                         "message": str(rec.detail.get("message", "")),
                                         "wall_s": rec.wall_s})
            elif rec.kind.removeprefix("operator.") in ACTIONS and rid not in self.entries:
                self.entries[rid] = JournalEntry(rid, rec.kind.removeprefix("operator."),
                                                 rec.source, rec.wall_s, earlier=True)
        for rid, entry in self.entries.items():
            entry.answer = answers.get(rid)
        self.entries = OrderedDict(sorted(self.entries.items(), key=lambda kv: kv[1].wall_s))
        while len(self.entries) > self.size:
            self.entries.popitem(last=False)
        self.unanswered_earlier = [e for e in self.entries.values() if e.answer is None]

    # --- queries ------------------------------------------------------------------------------

    def seen(self, request_id: str) -> bool:
        """The rover has received a command with this id (this run or an earlier one)."""
        return request_id in self.entries

    def lookup(self, request_id: str) -> dict[str, Any]:
        """What became of a command: its entry, or ``{request_id, state: "unknown"}``."""
        entry = self.entries.get(request_id)
        if entry is None:
            return {"request_id": request_id, "state": "unknown", "answer": None}
        return entry.to_json()

    # --- this run -----------------------------------------------------------------------------

    def _remember(self, entry: JournalEntry) -> None:
        self.entries[entry.request_id] = entry
        self.entries.move_to_end(entry.request_id)
        while len(self.entries) > self.size:
            self.entries.popitem(last=False)

    def on_command(self, cmd: OperatorCommand) -> None:
        """A command was published."""
        if cmd.request_id and cmd.request_id not in self.entries:
            self._remember(JournalEntry(cmd.request_id, cmd.action, cmd.source,
                                        self._wall(cmd.stamp)))

    def on_event(self, ev: Event) -> None:
        """An answer (other events are ignored)."""
        if ev.kind not in ANSWER_KINDS:
            return
        rid = str(ev.detail.get("request_id") or "")
        entry = self.entries.get(rid)
        if entry is not None and entry.answer is None:
            entry.answer = {"kind": ev.kind, "message": str(ev.detail.get("message", "")),
                            "wall_s": self._wall(ev.stamp)}

    def _wall(self, stamp: float) -> float:
        return round(self.clock.wall_time() - (self.clock.now() - stamp), 3)

    def answer_earlier(self) -> int:
        """Reject every command an earlier run received and never answered; return how many."""
        for entry in self.unanswered_earlier:
            self.bus.publish(EVENTS, Event(self.clock.now(), "bt.command_rejected", {
                "action": entry.action, "message": RESTART_ANSWER,
                "request_id": entry.request_id, "source": entry.source}))
            entry.answer = {"kind": "bt.command_rejected", "message": RESTART_ANSWER,
                            "wall_s": round(self.clock.wall_time(), 3)}
        count = len(self.unanswered_earlier)
        if count:
            log.info("answered %d command(s) the last run received but never answered", count)
        self.unanswered_earlier = []
        return count

    async def run(self) -> None:
        """Answer the earlier run's leftovers, then follow commands and answers until
        cancelled (every ``POLL_S``)."""
        self.answer_earlier()
        async for _ in self.clock.every(POLL_S, immediate=True):
            self.poll()

    def poll(self) -> None:
        """Take what was published since the last poll."""
        for cmd in self._ops.drain():
            self.on_command(cmd)
        for ev in self._events.drain():
            self.on_event(ev)

    async def close(self) -> None:
        """Stop following."""
        self._ops.close()
        self._events.close()

