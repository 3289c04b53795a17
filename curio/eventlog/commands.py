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

**Written ahead.** The journal is the one writer of commands and answers into the event log
(``operator.<action>`` with the command's ids, and the answer's kind; the event recorder leaves
both to it). A dashboard command is committed before it is published
(:meth:`CommandJournal.write_ahead`, awaited by :class:`~curio.web.control.RoverControl`
before the bus and the acknowledgement; the e-stop is published first and committed before
its acknowledgement), and an answer is committed before anyone hears it: the journal
republishes it on ``/operator/answers`` (``ANSWERS``) once it is in the log, and the dashboard
forwards answers from there. So a ``kill -9`` can never leave a page with an acknowledgement
the next run does not know, nor with an answer the next run contradicts: a command the next
run finds without an answer is answered "restarted before confirming" (it may have been begun;
nothing is resumed). While the disk is full the log cannot commit: commands and answers go on
at once, written when it has room, and ``not_durable`` counts them. Commands published
straight on the bus by other parts (the scheduler, the fleet link, scenarios) are written
behind, as they are seen.

History is read once at construction (a blocking read of the event log); records older than
``history_s`` of wall time are not answered any more (nobody waits for them).
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, get_args

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.jsonable import to_jsonable
from curio.core.messages import Event, OperatorAction, OperatorCommand
from curio.core.topics import ANSWERS, EVENTS, OPERATOR

from .store import EventLog, LogQuery

__all__ = ["ANSWER_KINDS", "RESTART_ANSWER", "CommandJournal", "JournalEntry", "command_record"]

log = logging.getLogger("curio.eventlog.commands")

ANSWER_KINDS = ("bt.command_accepted", "bt.command_rejected")
ACTIONS = frozenset(get_args(OperatorAction))
RESTART_ANSWER = ("Not confirmed: the rover restarted before answering this command (it may "
                  "have been begun), and nothing is resumed after a restart; check the rover "
                  "and send it again if you still want it.")


def command_record(cmd: OperatorCommand) -> tuple[str, dict[str, Any]]:
    """The event log's record of ``cmd``: ``(operator.<action>, {request_id, path_id?,
    tour_id?, goal?})``."""
    detail: dict[str, Any] = {"request_id": cmd.request_id}
    if cmd.path_id is not None:
        detail["path_id"] = cmd.path_id
    if cmd.tour_id is not None:
        detail["tour_id"] = cmd.tour_id
    if cmd.goal is not None:
        detail["goal"] = to_jsonable(cmd.goal, 4)
    return f"operator.{cmd.action}", detail


@dataclass
class JournalEntry:
    """One command and its answer.

    Attributes:
        request_id, action, source: as sent.
        wall_s: when it was published (UNIX seconds).
        earlier: it was received by an earlier run of Curio.
        answer: ``{kind, message, wall_s}`` once answered.
        logged: its record is in the event log (or queued for it).
    """

    request_id: str
    action: str
    source: str
    wall_s: float
    earlier: bool = False
    answer: dict[str, Any] | None = None
    logged: bool = False

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

    Attributes:
        not_durable: commands and answers that went on before their record was committed
            (the disk was full, or the commit took longer than ``COMMIT_WAIT_S``).
    """

    def __init__(self, bus: Bus, clock: Clock, eventlog: EventLog | None, size: int = 5000,
                 history_s: float = 86400.0) -> None:
        self.bus = bus
        self.clock = clock
        self.size = size
        self.history_s = history_s
        self.log = eventlog
        self.entries: OrderedDict[str, JournalEntry] = OrderedDict()
        self.unanswered_earlier: list[JournalEntry] = []
        self.not_durable = 0
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
                                                 rec.source, rec.wall_s, earlier=True,
                                                 logged=True)
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

    def _entry_for(self, cmd: OperatorCommand) -> JournalEntry | None:
        """The entry of ``cmd``, made and remembered if new; None without a request id."""
        if not cmd.request_id:
            return None
        entry = self.entries.get(cmd.request_id)
        if entry is None:
            entry = JournalEntry(cmd.request_id, cmd.action, cmd.source, self._wall(cmd.stamp))
            self._remember(entry)
        return entry

    async def write_ahead(self, cmd: OperatorCommand) -> bool:
        """Remember ``cmd`` and commit its record to the event log, before it is published
        (the e-stop: right after); True once committed. From now on ``seen`` knows its id.
        False without an event log, without a request id (written when seen on the bus), or
        when the log could not commit in time (counted in ``not_durable``; the record is
        still written when the log can)."""
        entry = self._entry_for(cmd)
        if entry is None or self.log is None or entry.logged:
            return False
        entry.logged = True
        kind, detail = command_record(cmd)
        return await self._commit(kind, detail, entry.wall_s, cmd.source)

    async def _commit(self, kind: str, detail: dict[str, Any], wall_s: float,
                      source: str) -> bool:
        """Write one record and wait for its commit (inline on a simulated clock, in a worker
        thread on the real one); count it in ``not_durable`` when that failed."""
        assert self.log is not None
        committed = await self.clock.offload(functools.partial(
            self.log.append_committed, kind, detail, wall_s=wall_s, source=source))
        if not committed:
            self.not_durable += 1
        return bool(committed)

    def on_command(self, cmd: OperatorCommand) -> None:
        """A command was published: remember it, and write its record unless it was written
        ahead."""
        entry = self._entry_for(cmd)
        if entry is not None:
            if entry.logged:
                return
            entry.logged = True
        if self.log is not None:
            kind, detail = command_record(cmd)
            self.log.append(kind, detail, wall_s=self._wall(cmd.stamp), source=cmd.source)

    def on_event(self, ev: Event) -> None:
        """An answer: noted on its command (other events are ignored)."""
        if ev.kind not in ANSWER_KINDS:
            return
        rid = str(ev.detail.get("request_id") or "")
        entry = self.entries.get(rid)
        if entry is not None and entry.answer is None:
            entry.answer = {"kind": ev.kind, "message": str(ev.detail.get("message", "")),
                            "wall_s": self._wall(ev.stamp)}

    async def deliver(self, ev: Event) -> None:
        """An answer: noted, committed to the event log, then published on ``ANSWERS`` for
        whoever tells the operator (other events are ignored)."""
        if ev.kind not in ANSWER_KINDS:
            return
        self.on_event(ev)
        if self.log is not None:
            source = ev.detail.get("source", "")
            await self._commit(ev.kind, dict(ev.detail), self._wall(ev.stamp),
                               source if isinstance(source, str) else "")
        self.bus.publish(ANSWERS, ev)

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
        cancelled."""
        self.answer_earlier()
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._follow_commands(), name="commands.follow")
            tg.create_task(self._follow_answers(), name="commands.answers")

    async def _follow_commands(self) -> None:
        async for cmd in self._ops:
            self.on_command(cmd)

    async def _follow_answers(self) -> None:
        async for ev in self._events:
            if ev.kind in ANSWER_KINDS:
                self.poll()  # its command first: it was published before its answer
                await self.deliver(ev)

    def poll(self) -> None:
        """Take the commands published since the last look (tests; the answers' follower)."""
        for cmd in self._ops.drain():
            self.on_command(cmd)

    async def close(self) -> None:
        """Stop following (what is queued is taken first)."""
        self.poll()
        for ev in self._events.drain():
            await self.deliver(ev)
        self._ops.close()
        self._events.close()
