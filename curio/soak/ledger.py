"""The ledger of operator commands: was every one answered exactly once, none lost, none
replayed?

Two views, kept apart:

* **the operators'** — what each scripted client sent (a ``request_id`` of its own) and what it
  was told: a refusal from the dashboard itself (``{"t": "error"}`` with a reason: a viewer, a
  bad value, an unknown action), or the rover's answer, ``bt.command_accepted`` /
  ``bt.command_rejected`` carrying the ``request_id`` — seen live on the WebSocket, in the
  history a reconnecting page receives, or asked for after a reconnection
  (``GET /api/commands/{request_id}``);
* **the rover's** — every command it published on ``/operator`` and every answer it gave, in
  which run (``boot``), as its soak reporter forwarded them.

A command is **answered** when its client got a final answer; **double-answered** when its
client got two different ones, or the rover gave two; **lost** when the rover published it but
its client never got an answer (nor did the rover give one); **not delivered** when it never
reached the rover (the socket went down first) and the rover says it does not know it —
the client knows, which is not a loss; **replayed** when the rover published it more than once
(in one run or in two); **pending at the end** when the rover published it in its last run no
more than ``PENDING_WINDOW_S`` before the soak's end, had not answered it yet, and said it
was still carrying it out (``pending``) when last asked: the end cut the command short (a
docked rover backs out for some 6 s before it answers "Tour started"); **answered at the
end** when the rover answered it in the last ``END_WINDOW_S`` before the soak's end, as the
clients stopped listening, and the client got no answer: the end cut the delivery, not the
rover. Any other command the rover never answered is lost, whenever it was sent.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

__all__ = ["CommandRecord", "Ledger"]

ANSWER_KINDS = ("bt.command_accepted", "bt.command_rejected")
END_WINDOW_S = 1.0  # simulated s before the rover's end: an answer then may meet no client
PENDING_WINDOW_S = 15.0  # simulated s before the end: a command still carried out is not lost


@dataclass
class CommandRecord:
    """One command a client sent.

    Attributes:
        rid: its request id.
        client: the sender (``<role>:<name>#<n>``).
        action: the action (or what was sent, for malformed ones).
        expect: ``answer`` (a valid command: the rover answers) or ``refusal`` (the dashboard
            must refuse it).
        sent_wall_s: when (the orchestrator's monotonic clock).
        acked: the dashboard acknowledged publishing it (``{"t": "ack"}``).
        answers: the distinct final answers the client received: ``(kind, message)``.
        via: how each answer came (``ws``, ``history``, ``lookup``, ``refusal``).
    """

    rid: str
    client: str
    action: str
    expect: str
    sent_wall_s: float
    acked: bool = False
    answers: dict[tuple[str, str, float], str] = field(default_factory=dict)
    lookups: list[str] = field(default_factory=list)
    disconnected: bool = False
    duplicate_ack: bool = False

    @property
    def answered(self) -> bool:
        """It has a final answer."""
        return bool(self.answers)


class Ledger:
    """Both views and the verdicts (see the module docstring)."""

    def __init__(self) -> None:
        self.commands: dict[str, CommandRecord] = {}
        self.published: dict[str, list[tuple[int, float]]] = {}  # each publication: boot, s
        self.rover_answers: dict[str, list[tuple[int, str, str, float]]] = {}
        self.malformed_sent = 0
        self.malformed_refused = 0

    # --- the operators' view ------------------------------------------------------------------

    def sent(self, rid: str, client: str, action: str, expect: str, at_s: float) -> None:
        """A client sent a command."""
        self.commands[rid] = CommandRecord(rid, client, action, expect, at_s)

    def acked(self, rid: str, duplicate: bool) -> None:
        """The dashboard acknowledged it."""
        rec = self.commands.get(rid)
        if rec is not None:
            rec.acked = True
            rec.duplicate_ack = rec.duplicate_ack or duplicate

    def answer(self, rid: str, kind: str, message: str, wall_s: float, via: str) -> None:
        """Its client got a final answer, given at ``wall_s`` (the rover's wall clock, UNIX s;
        0 for the dashboard's refusals): the same answer seen twice — live and in a lookup —
        counts once (to the hundredth of a second: a lookup's time is rounded to the
        millisecond)."""
        rec = self.commands.get(rid)
        if rec is None:
            return
        key = (kind, message, round(wall_s, 2))
        rec.answers.setdefault(key, via)

    def pending(self, client: str) -> list[CommandRecord]:
        """The client's commands without an answer."""
        return [r for r in self.commands.values() if r.client == client and not r.answered]

    # --- the rover's view ---------------------------------------------------------------------

    def rover_event(self, boot: int, kind: str, detail: dict[str, Any], stamp: float) -> None:
        """An ``operator`` publication or an answer, forwarded by the rover of run ``boot``."""
        rid = str(detail.get("request_id") or "")
        if not rid:
            return
        if kind == "operator":
            self.published.setdefault(rid, []).append((boot, stamp))
        elif kind in ANSWER_KINDS:
            self.rover_answers.setdefault(rid, []).append(
                (boot, kind, str(detail.get("message", "")), stamp))

    # --- verdicts -----------------------------------------------------------------------------

    def _rover_double(self, rid: str) -> bool:
        answers = self.rover_answers.get(rid, [])
        return len({(k, m, round(s, 3)) for _, k, m, s in answers}) > 1

    def _answered_at_end(self, rid: str, end: tuple[int, float] | None) -> bool:
        if end is None:
            return False
        boot, end_s = end
        return any(b == boot and stamp >= end_s - END_WINDOW_S
                   for b, _, _, stamp in self.rover_answers.get(rid, []))

    def _pending_at_end(self, rec: CommandRecord, end: tuple[int, float] | None) -> bool:
        if end is None or self.rover_answers.get(rec.rid) or not rec.lookups \
                or rec.lookups[-1] != "pending":
            return False
        boot, end_s = end
        published = self.published.get(rec.rid, [])
        return bool(published) and published[-1][0] == boot and \
            published[-1][1] >= end_s - PENDING_WINDOW_S

    def summary(self, end: tuple[int, float] | None = None) -> dict[str, Any]:
        """Counts, the verdicts and a few examples of each problem; ``end``: the last run's
        boot and the simulated time it ended at (None: it did not reach its end)."""
        counts: Counter[str] = Counter()
        examples: dict[str, list[dict[str, Any]]] = {}

        def note(what: str, rec: CommandRecord) -> None:
            counts[what] += 1
            examples.setdefault(what, [])
            if len(examples[what]) < 8:
                examples[what].append({"rid": rec.rid, "client": rec.client,
                                       "action": rec.action, "acked": rec.acked,
                                       "answers": [list(k) for k in rec.answers],
                                       "published_in": [b for b, _ in
                                                        self.published.get(rec.rid, [])],
                                       "lookups": rec.lookups[-3:]})

        for rec in self.commands.values():
            counts["sent"] += 1
            counts[f"expect_{rec.expect}"] += 1
            published = self.published.get(rec.rid, [])
            if rec.answered:
                counts["answered"] += 1
                kinds = {k[0] for k in rec.answers}
                for kind in kinds:
                    counts[kind.replace("bt.command_", "")] += 1
            if len(rec.answers) > 1 or self._rover_double(rec.rid):
                note("double_answered", rec)
            if len(published) > 1:
                note("replayed", rec)
            if not rec.answered:
                if self._answered_at_end(rec.rid, end):
                    note("answered_at_end", rec)
                elif self._pending_at_end(rec, end):
                    note("pending_at_end", rec)
                elif published or self.rover_answers.get(rec.rid):
                    note("lost", rec)
                elif "unknown" in rec.lookups or not rec.acked:
                    note("not_delivered", rec)
                else:
                    note("lost", rec)
            if rec.expect == "refusal" and rec.answered and \
                    "refused" not in {k[0] for k in rec.answers}:
                note("invalid_accepted", rec)
        return {"counts": dict(counts), "examples": examples,
                "malformed_sent": self.malformed_sent,
                "malformed_refused": self.malformed_refused}
