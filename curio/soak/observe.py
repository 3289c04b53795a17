"""What the orchestrator learns from the rover's report lines (:mod:`curio.soak.link`), across
every run of the rover: the latest beat, the faults and their verdicts, collisions, tours,
resource samples and cycle-time histograms, and what each restart looked like.

:class:`Observations` takes each parsed line (:meth:`Observations.take`); the report
(:mod:`curio.soak.report`) reads its fields.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from curio.soak.ledger import Ledger
from curio.soak.plan import KIDNAP_KINDS
from curio.soak.probes import Histogram

__all__ = ["DRIVING_STATES", "MOTION_PERMITS", "Observations", "RestartWatch", "Stillness"]

# The rover's states in which it has somewhere to drive (a tour, a path, a goal, home).
DRIVING_STATES = frozenset({"tour", "moving", "going_home"})
# Moving this far (true position, m) from where it stood ends a stretch of standing still.
STILL_RADIUS_M = 0.5

# Events after which the rover may move: an operator's or the schedule's say-so.
MOTION_PERMITS = ("bt.command_accepted", "tour.started", "tour.scheduled_start",
                  "operator.teleop")
STILL_M = 0.05


@dataclass
class RestartWatch:
    """One restart: what the killed rover was doing and what the new one did first."""

    boot: int
    fault_id: int
    kind: str
    killed_sim_s: float
    killed_wall_s: float
    truth: list[float]
    tour_at_kill: Any
    estop_at_kill: bool
    started_wall: float = 0.0
    start_truth: list[float] | None = None
    moved_m: float = 0.0
    permitted: str | None = None
    interrupted_reported: bool = False
    estop_after: bool | None = None
    unclean_reported: bool = False
    files: list[dict[str, Any]] = field(default_factory=list)
    corruption: dict[str, Any] | None = None
    data_after: list[dict[str, Any]] = field(default_factory=list)
    start_pose_error_m: float | None = None
    carried: int = 0
    rebased: int = 0
    # Commands the rover acted on and then refused (request ids): their motion was theirs.
    excused: list[str] = field(default_factory=list)
    rebase_next: bool = False
    # Until permitted: the commands sent (request id → simulated s) and how far the rover
    # was from where it started at each beat (simulated s, m).
    commands: dict[str, float] = field(default_factory=dict)
    path: list[tuple[float, float]] = field(default_factory=list)

    def permit(self, kind: str, request_id: str | None, sim_s: float) -> None:
        """Motion permitted by ``kind``; an accepted command permits from when it was sent
        (a docked rover backs out of its dock first and answers "Tour started" after)."""
        self.permitted = kind
        since = self.commands.get(request_id or "", sim_s)
        self.moved_m = max((d for t, d in self.path if t <= since), default=0.0)
        self.commands.clear()
        self.path.clear()

    def excuse(self, request_id: str | None) -> None:
        """A command the rover began to carry out and then refused (a docked rover backing out
        for a tour when a pause or a kidnap came first, and the tour is refused): its motion,
        from when it was sent to the refusal, was the command's. Watching goes on from where
        the rover stands at the next beat. Nothing is excused when the rover had not moved
        since it was sent: a command refused at once permits nothing."""
        since = self.commands.get(request_id or "")
        if since is None or not any(t > since and d > STILL_M for t, d in self.path):
            return
        self.moved_m = max((d for t, d in self.path if t <= since), default=0.0)
        self.path.clear()
        self.excused.append(str(request_id))
        self.rebase_next = True

    def to_json(self) -> dict[str, Any]:
        """Plain JSON for the report."""
        return {k: v for k, v in self.__dict__.items()
                if k not in ("commands", "path", "rebase_next")}


@dataclass
class Stillness:
    """How long the rover stood still while it had somewhere to drive: simulated seconds in
    :data:`DRIVING_STATES` during which its true position stayed within
    :data:`STILL_RADIUS_M` of where it stood; a new process or a kidnap starts afresh. A
    rover that stands for minutes with a tour to give is out of service, whatever else works
    (a wedge along a wall, a rover and a walker waiting for each other, in the soaks of
    2026-12-02)."""

    longest_s: float = 0.0
    longest_at: dict[str, Any] | None = None
    _anchor: tuple[int, float, float] | None = None
    _still_s: float = 0.0
    _last_s: float | None = None

    def restart(self) -> None:
        """Forget where it stood (a new process, or it was carried)."""
        self._anchor, self._still_s, self._last_s = None, 0.0, None

    def beat(self, boot: int, sim_s: float, truth: list[float], state: str | None) -> None:
        """One heartbeat: the process, its clock (s), the true pose (map) and its state."""
        a = self._anchor
        if a is None or a[0] != boot or math.hypot(truth[0] - a[1],
                                                   truth[1] - a[2]) >= STILL_RADIUS_M:
            self._anchor, self._still_s = (boot, truth[0], truth[1]), 0.0
        elif self._last_s is not None and state in DRIVING_STATES:
            self._still_s += max(0.0, sim_s - self._last_s)
            if self._still_s > self.longest_s:
                self.longest_s = self._still_s
                self.longest_at = {"boot": boot, "sim_s": sim_s,
                                   "x": round(truth[0], 2), "y": round(truth[1], 2)}
        self._last_s = sim_s


class Observations:
    """Everything the rover reported (see the module docstring)."""

    def __init__(self, ledger: Ledger) -> None:
        self.ledger = ledger
        self.beat: dict[str, Any] | None = None
        self.first_beat: dict[str, Any] | None = None
        self.hellos: list[dict[str, Any]] = []
        self.faults: dict[int, dict[str, Any]] = {}
        self.injected: dict[int, dict[str, Any]] = {}
        self.collisions: list[dict[str, Any]] = []
        self.kinds: Counter[str] = Counter()
        self.res: list[dict[str, Any]] = []
        self.nav_cpu, self.nav_wall = Histogram(), Histogram()
        self.safety_cpu, self.safety_wall = Histogram(), Histogram()
        self.safety_rates: list[dict[str, Any]] = []
        self.restarts: list[RestartWatch] = []
        self.watch: RestartWatch | None = None
        self.ends: list[dict[str, Any]] = []
        self.notable: list[dict[str, Any]] = []
        self.still = Stillness()
        self.lines = 0

    def take(self, msg: dict[str, Any]) -> None:
        """One line from the rover."""
        self.lines += 1
        t = msg.get("t")
        if t == "beat":
            self._beat(msg)
        elif t == "ev":
            self._event(msg)
        elif t == "fault":
            if msg.get("phase") == "injected":
                self.injected[int(msg["id"])] = msg
                if msg.get("kind") in KIDNAP_KINDS:
                    self.still.restart()  # carried off: it stands somewhere else now
                self._carried(msg)
            else:
                self.faults[int(msg["id"])] = msg
        elif t == "res":
            self._res(msg)
        elif t == "hello":
            self.hellos.append(msg)
        elif t in ("done", "stopped", "end"):
            self.ends.append(msg)

    def _carried(self, msg: dict[str, Any]) -> None:
        """A kidnap injected while a restarted rover is watched: the soak carried it, so its
        stillness is measured from where it was put down (the first beat after)."""
        w = self.watch
        if (w is not None and w.boot == msg.get("boot") and w.permitted is None
                and msg.get("kind") in KIDNAP_KINDS):
            w.carried += 1  # the next beat moves start_truth where it was put down

    def _beat(self, msg: dict[str, Any]) -> None:
        self.beat = msg
        if self.first_beat is None:
            self.first_beat = msg
        if msg.get("truth") is not None and msg.get("sim_s") is not None:
            self.still.beat(int(msg.get("boot", 0)), float(msg["sim_s"]), msg["truth"],
                            msg.get("status"))
        w = self.watch
        if w is None or w.boot != msg.get("boot"):
            return
        truth = msg.get("truth") or [0.0, 0.0, 0.0]
        if w.start_truth is not None and (w.carried > w.rebased or w.rebase_next):
            w.start_truth, w.rebased, w.rebase_next = truth, w.carried, False
        if w.start_truth is None:
            w.start_truth = truth
            w.estop_after = msg.get("estop")
            pose = msg.get("pose")
            if pose is not None:
                w.start_pose_error_m = round(math.hypot(pose[0] - truth[0],
                                                        pose[1] - truth[1]), 3)
        if w.permitted is None:
            moved = math.hypot(truth[0] - w.start_truth[0], truth[1] - w.start_truth[1])
            w.moved_m = max(w.moved_m, moved)
            w.path.append((float(msg.get("sim_s") or 0.0), moved))

    def _event(self, msg: dict[str, Any]) -> None:
        kind = str(msg.get("kind", ""))
        detail = msg.get("detail") or {}
        boot = int(msg.get("boot", 0))
        self.kinds[kind] += 1
        self.ledger.rover_event(boot, kind, detail, float(msg.get("sim_s", 0.0)))
        if kind == "collision":
            self.collisions.append({"boot": boot, "sim_s": msg.get("sim_s"), **detail})
        if kind.startswith(("system.", "data.", "tour.interrupted", "loop.")):
            self.notable.append({"boot": boot, "kind": kind, "sim_s": msg.get("sim_s"),
                                 "detail": detail})
        w = self.watch
        if w is None or w.boot != boot:
            return
        if kind == "tour.interrupted":
            w.interrupted_reported = True
        if kind == "system.unclean_restart":
            w.unclean_reported = True
        if w.permitted is None and kind == "operator" and detail.get("request_id"):
            w.commands.setdefault(str(detail["request_id"]), float(msg.get("sim_s", 0.0)))
        if w.permitted is None and kind == "bt.command_rejected":
            w.excuse(detail.get("request_id"))
        if w.permitted is None and kind in MOTION_PERMITS:
            w.permit(kind, detail.get("request_id"), float(msg.get("sim_s", 0.0)))

    def _res(self, msg: dict[str, Any]) -> None:
        for name, cpu, wall in (("nav", self.nav_cpu, self.nav_wall),
                                ("safety", self.safety_cpu, self.safety_wall)):
            block = msg.get(name) or {}
            cpu.merge(Histogram.from_json(block.get("cpu", {})))
            wall.merge(Histogram.from_json(block.get("wall", {})))
        rate = msg.get("safety_rate")
        if rate:
            self.safety_rates.append({"boot": msg.get("boot"), "sim_s": msg.get("sim_s"),
                                      **rate})
        keep = {k: v for k, v in msg.items() if k not in ("nav", "safety", "t")}
        self.res.append(keep)

    def restart_begins(self, watch: RestartWatch) -> None:
        """A restart: judge what the next rover does first."""
        self.restarts.append(watch)
        self.watch = watch
