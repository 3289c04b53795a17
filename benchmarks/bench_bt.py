"""Behaviour-tree benchmark: the cost of one tick of Curio's full trees.

``curio bench bt [--pairs N]`` (N = ticks per case, default 4000)

Each case builds the real tree (``build_tree_runner`` with the shipped ``[bt]`` defaults) on a
scripted navigator that accepts every goal at once, and times ``TreeRunner.tick()`` — feeds,
priorities, the follower, the blackboard mirror, the change detection and, when something
changed, the TreeSnapshot built and published:

* ``follow_path steady``: driving a long path; nothing changes between ticks (the common case).
* ``follow_path busy``: every tick something happens: a waypoint is reached (status, progress,
  events, a snapshot), every 20th tick an operator command (pause/resume, path changes, Go
  Home), BLOCKED toggling every 50 ticks (help requests and their resolution).
* ``tour busy``: the tour tree with dwell stops, the battery feed and the same events.

Figures: per-tick wall time (median, mean, p99 in ms), CPU time per tick (mean), snapshots
published per 100 ticks. Target: median ≤ 1 ms.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

from curio.bt.paths import PathManager, Waypoint
from curio.bt.runner import build_tree_runner
from curio.commands.bench import BenchOptions
from curio.core.config import BtConfig, TourStopConfig
from curio.core.geometry import Pose2D
from curio.core.messages import BatteryState, BlockedState, OperatorCommand
from curio.core.topics import BATTERY, BLOCKED, EVENTS, OPERATOR, PROGRESS, STATUS, TREE, make_bus
from curio.nav.api import GoalHandle, GoalState


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def wall_time(self) -> float:
        return self.t

    async def sleep(self, dt_s: float) -> None:  # pragma: no cover - unused
        raise NotImplementedError

    async def sleep_until(self, t_s: float) -> None:  # pragma: no cover - unused
        raise NotImplementedError


class _Navigator:
    """Accepts every goal (ACTIVE); the benchmark ends them."""

    def __init__(self) -> None:
        self._active: GoalHandle | None = None
        self.n = 0

    def send_goal(self, poses: Pose2D | list[Pose2D], *, tag: str = "") -> GoalHandle:
        if self._active is not None and not self._active.done:
            self._active.state = GoalState.PREEMPTED
        self.n += 1
        handle = GoalHandle(self.n, [poses] if isinstance(poses, Pose2D) else list(poses),
                            state=GoalState.ACTIVE, tag=tag)
        self._active = handle
        return handle

    def cancel(self) -> None:
        if self._active is not None and not self._active.done:
            self._active.state = GoalState.PREEMPTED
        self._active = None

    @property
    def active(self) -> GoalHandle | None:
        return self._active if self._active is not None and not self._active.done else None

    def succeed(self) -> None:
        if self._active is not None:
            self._active.state = GoalState.SUCCEEDED
            self._active = None


def _case(name: str, cfg: BtConfig, ticks: int, busy: bool) -> dict[str, Any]:
    bus = make_bus()
    clock = _Clock()
    nav = _Navigator()
    paths = PathManager(cfg.paths, None)
    long_path = paths.create("Long", [Waypoint(float(i % 20), float(i // 20), None)
                                      for i in range(200)]).id
    runner = build_tree_runner(cfg, bus, clock, nav, paths)
    subs = [bus.subscribe(t) for t in (STATUS, PROGRESS, EVENTS, TREE)]
    start = "start_tour" if cfg.tree == "tour" else "select_path"
    bus.publish(OPERATOR, OperatorCommand(0.0, start, path_id=long_path))  # type: ignore[arg-type]
    if cfg.tree == "tour":
        bus.publish(BATTERY, BatteryState(0.0, 7.4))
    script = ["pause", "resume", "select_path", "go_home", "select_path", "resume"]
    wall: list[float] = []
    cpu_total = 0.0
    snapshots = 0
    for i in range(ticks):
        clock.t += runner.period_s
        if busy:
            if i % 2 == 0:
                nav.succeed()
            if i % 20 == 10:
                action = script[(i // 20) % len(script)]
                path_id = long_path if action == "select_path" else None
                if cfg.tree == "tour" and action == "select_path":
                    action = "start_tour"
                bus.publish(OPERATOR, OperatorCommand(clock.t, action,  # type: ignore[arg-type]
                                                      path_id=path_id))
            if i % 50 == 25:
                bus.publish(BLOCKED, BlockedState(clock.t, (i // 50) % 2 == 0, 0.8))
        c0 = time.process_time()
        w0 = time.perf_counter()
        snap = runner.tick()
        wall.append((time.perf_counter() - w0) * 1000.0)
        cpu_total += time.process_time() - c0
        snapshots += snap is not None
        for sub in subs:
            sub.drain()
    wall_sorted = sorted(wall)
    return {
        "subject": "curio",
        "case": name,
        "nodes": len(runner.snapshot().nodes),
        "ticks": ticks,
        "median_ms": round(statistics.median(wall), 4),
        "mean_ms": round(statistics.fmean(wall), 4),
        "p99_ms": round(wall_sorted[min(len(wall) - 1, int(0.99 * len(wall)))], 4),
        "cpu_mean_ms": round(cpu_total / ticks * 1000.0, 4),
        "snapshots_per_100_ticks": round(100.0 * snapshots / ticks, 1),
        "goals_sent": nav.n,
    }


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """One row per case."""
    ticks = opts.pairs or 4000
    stops = [TourStopConfig(name=f"Stop {i}", x_m=float(i), y_m=0.0, dwell_s=1.0,
                            message=f"Stop number {i}.") for i in range(8)]
    return [
        _case("follow_path steady", BtConfig(speak=False), ticks, busy=False),
        _case("follow_path busy", BtConfig(speak=False), ticks, busy=True),
        _case("tour busy", BtConfig(speak=False, tree="tour", tour_stops=stops,
                                    tour_loop=True), ticks, busy=True),
    ]
