"""Scripted fakes for the behaviour-tree tests: a navigator, a manual clock, a tree harness."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from curio.bt.paths import PathManager
from curio.bt.runner import TreeRunner, build_tree_runner
from curio.bt.speech import Speaker
from curio.core.bus import Bus, Subscription
from curio.core.config import BtConfig
from curio.core.geometry import Pose2D
from curio.core.messages import (
    BatteryState,
    BlockedState,
    EStop,
    Event,
    OperatorCommand,
    Progress,
    StatusText,
)
from curio.core.topics import BATTERY, BLOCKED, ESTOP, EVENTS, OPERATOR, PROGRESS, STATUS, make_bus
from curio.nav.api import GoalHandle, GoalState, NavError, NoPathError


class ManualClock:
    """A clock the test moves by hand (ticks are synchronous)."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def now(self) -> float:
        return self.t

    def wall_time(self) -> float:
        return 1_700_000_000.0 + self.t

    async def sleep(self, dt_s: float) -> None:  # pragma: no cover - not used by tick()
        raise NotImplementedError

    async def sleep_until(self, t_s: float) -> None:  # pragma: no cover
        raise NotImplementedError


class FakeNavigator:
    """Accepts every goal at once (ACTIVE); the test decides how each one ends."""

    def __init__(self) -> None:
        self.goals: list[GoalHandle] = []
        self._active: GoalHandle | None = None
        self.cancels = 0
        self.reject_next: NavError | None = None

    def send_goal(self, poses: Pose2D | list[Pose2D], *, tag: str = "") -> GoalHandle:
        pose_list = [poses] if isinstance(poses, Pose2D) else list(poses)
        if self._active is not None and not self._active.done:
            self._active.state = GoalState.PREEMPTED
        handle = GoalHandle(len(self.goals) + 1, pose_list, tag=tag)
        self.goals.append(handle)
        if self.reject_next is not None:
            handle.state = GoalState.REJECTED
            handle.error = self.reject_next
            self.reject_next = None
            self._active = None
            return handle
        handle.state = GoalState.ACTIVE
        self._active = handle
        return handle

    def cancel(self) -> None:
        self.cancels += 1
        if self._active is not None and not self._active.done:
            self._active.state = GoalState.PREEMPTED
        self._active = None

    @property
    def active(self) -> GoalHandle | None:
        if self._active is not None and self._active.done:
            return None
        return self._active

    # --- test controls ---
    @property
    def last(self) -> GoalHandle:
        return self.goals[-1]

    def target(self) -> tuple[float, float]:
        pose = self.last.poses[-1]
        return (round(pose.x, 3), round(pose.y, 3))

    def succeed(self) -> None:
        assert self._active is not None, "no active goal to succeed"
        self._active.state = GoalState.SUCCEEDED
        self._active = None

    def abort(self, error: NavError | None = None) -> None:
        assert self._active is not None, "no active goal to abort"
        self._active.state = GoalState.ABORTED
        self._active.error = error or NoPathError("No path to the goal.")
        self._active = None


@dataclass
class Harness:
    """One tree on a fake navigator and a manual clock, with recorders."""

    runner: TreeRunner
    nav: FakeNavigator
    clock: ManualClock
    bus: Bus
    paths: PathManager
    status_sub: Subscription[StatusText]
    events_sub: Subscription[Event]
    progress_sub: Subscription[Progress]
    speaker: Speaker
    statuses: list[StatusText] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    progress: list[Progress] = field(default_factory=list)

    def tick(self, n: int = 1, dt: float | None = None) -> None:
        step = self.runner.period_s if dt is None else dt
        for _ in range(n):
            self.clock.t += step
            self.runner.tick()
            self.collect()

    def collect(self) -> None:
        self.statuses += self.status_sub.drain()
        self.events += self.events_sub.drain()
        self.progress += self.progress_sub.drain()

    def press(self, action: Any, **kwargs: Any) -> None:
        self.bus.publish(OPERATOR, OperatorCommand(self.clock.now(), action, source="test",
                                                   **kwargs))

    def blocked(self, flag: bool, distance: float | None = 0.8) -> None:
        self.bus.publish(BLOCKED, BlockedState(self.clock.now(), flag,
                                               distance if flag else None))

    def estop(self, engaged: bool) -> None:
        self.bus.publish(ESTOP, EStop(self.clock.now(), engaged, source="test"))

    def battery(self, volts: float) -> None:
        self.bus.publish(BATTERY, BatteryState(self.clock.now(), volts))

    # --- queries ---
    @property
    def status(self) -> StatusText:
        return self.statuses[-1]

    def texts(self) -> list[str]:
        return [s.text for s in self.statuses]

    def kinds(self, prefix: str = "") -> list[str]:
        return [e.kind for e in self.events if e.kind.startswith(prefix)]

    def of(self, kind: str) -> list[Event]:
        return [e for e in self.events if e.kind == kind]

    def last_message(self, kind: str) -> str:
        events = self.of(kind)
        assert events, f"no {kind} event; events: {self.kinds()}"
        return str(events[-1].detail["message"])

    def bb(self, key: str) -> Any:
        return self.runner.blackboard()[key]

    def node(self, name: str) -> Any:
        for node in self.runner._nodes:
            if node.name == name:
                return node
        raise KeyError(name)

    def clear(self) -> None:
        self.collect()
        self.statuses.clear()
        self.events.clear()
        self.progress.clear()


def make_harness(cfg: BtConfig | None = None, *, navigator: Any = "fake",
                 paths: PathManager | None = None, bus: Bus | None = None,
                 autostart_path: int | None = None, docker: Any = None) -> Harness:
    cfg = cfg or BtConfig(speak=False)
    bus = bus or make_bus()
    clock = ManualClock()
    nav = FakeNavigator() if navigator == "fake" else navigator
    paths = paths or PathManager(cfg.paths, None)
    speaker = Speaker(enabled=False)
    status_sub = bus.subscribe(STATUS)
    events_sub = bus.subscribe(EVENTS)
    progress_sub = bus.subscribe(PROGRESS)
    runner = build_tree_runner(cfg, bus, clock, nav, paths, speaker,
                               autostart_path=autostart_path, docker=docker)
    return Harness(runner, nav, clock, bus, paths, status_sub, events_sub, progress_sub,
                   speaker)
