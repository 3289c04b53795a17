"""Scenario framework: run the whole application on the simulated clock with a script.

A scenario is a class with a ``name``, an optional :meth:`Scenario.configure` that adjusts the
config, and :meth:`Scenario.run`, an async script that schedules timed events (close a door,
place an obstacle, teleport the rover, press a dashboard button), waits for conditions and
records checks. :func:`run_scenario` builds the :class:`~curio.app.App` on a
:class:`~curio.core.clock.SimClock`, runs the script, and returns the report of DESIGN.md's
contract.

Scenarios do not record unless asked: ``ScenarioArgs.record`` (``curio sim … --record
FILE.mcap``) turns the flight recorder on for that one file. Goals a script gives the navigator
through :meth:`ScenarioContext.navigator_ready`'s handle are published on ``/goal`` too, so
``curio replay`` can give them again.

Report fields: ``scenario``, ``seed``, ``success``, ``sim_time_s``, ``wall_time_s``,
``goals_reached``, ``goals_total``, ``collisions``, ``path_length_m`` (ground-truth distance
driven), ``localization_rmse_m`` (null when localisation is off), ``events``
(``[{t, kind, detail}]``), plus ``checks`` and scenario-specific ``metrics``.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import logging
import math
import shutil
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from curio.app import App
from curio.core.clock import SimClock, wall_perf_counter
from curio.core.config import Config
from curio.core.fileio import atomic_write_json
from curio.core.geometry import Pose2D
from curio.core.jsonable import to_jsonable
from curio.core.messages import (
    Event,
    NavGoal,
    OperatorAction,
    OperatorCommand,
    PoseWithCovariance,
)
from curio.core.topics import EVENTS, GOAL, GROUND_TRUTH, OPERATOR, POSE
from curio.drivers.modes import driver_mode

__all__ = ["Scenario", "ScenarioArgs", "ScenarioContext", "ScenarioFailed", "run_scenario"]

log = logging.getLogger("curio.scenario")


class ScenarioFailed(Exception):
    """Raised by a script to end the scenario as failed, with the reason."""


@dataclass
class ScenarioArgs:
    """Command-line arguments of ``curio sim`` (all optional)."""

    map_yaml: str | None = None
    start: tuple[float, float, float] | None = None
    goal: tuple[float, float, float | None] | None = None
    seed: int | None = None
    speed: float | None = None
    duration_s: float | None = None
    web: bool = False
    record: Path | None = None
    visitors: int | None = None  # simulated visitors (sim.crowd.visitors)


@dataclass
class Check:
    """One named check of a scenario."""

    name: str
    ok: bool
    detail: str = ""


@dataclass
class _Metrics:
    path_length_m: float = 0.0
    last_truth: Pose2D | None = None
    truth_history: list[tuple[float, Pose2D]] = field(default_factory=list)
    sq_err_sum: float = 0.0
    sq_yaw_err_sum: float = 0.0
    max_err_m: float = 0.0
    err_count: int = 0


class ScenarioContext:
    """What a scenario script works with."""

    def __init__(self, app: App, clock: SimClock, args: ScenarioArgs) -> None:
        self.app = app
        self.clock = clock
        self.bus = app.bus
        self.args = args
        self.cfg = app.cfg
        self.events: list[dict[str, Any]] = []
        self.checks: list[Check] = []
        self.metrics: dict[str, Any] = {}
        self.goals_total = 0
        self.goals_reached = 0
        self._timers: list[asyncio.Task[None]] = []

    @property
    def world(self) -> Any:
        """The simulated world (``app.world``)."""
        return self.app.world

    def now(self) -> float:
        """Simulated time, seconds."""
        return self.clock.now()

    def record(self, kind: str, **detail: Any) -> None:
        """Publish a scenario event on ``/events`` (it lands in the report)."""
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, dict(detail)))

    def check(self, name: str, ok: bool, detail: str = "") -> bool:
        """Record a named check; a failed check fails the scenario."""
        self.checks.append(Check(name, bool(ok), detail))
        self.record("check", name=name, ok=bool(ok), detail=detail)
        return bool(ok)

    def press(self, action: OperatorAction, **kwargs: Any) -> None:
        """Press a dashboard button: publish an operator command (reliable)."""
        self.bus.publish(
            OPERATOR, OperatorCommand(self.clock.now(), action, source="scenario", **kwargs)
        )

    def at(self, t_s: float, action: Callable[[], Any], label: str = "") -> None:
        """Run ``action`` at simulated time ``t_s`` (a coroutine function or a plain one)."""

        async def fire() -> None:
            await self.clock.sleep_until(t_s)
            if label:
                self.record("script", action=label)
            result = action()
            if asyncio.iscoroutine(result):
                await result

        self._timers.append(asyncio.create_task(fire(), name=f"script@{t_s}"))

    async def sleep(self, dt_s: float) -> None:
        """Sleep simulated seconds."""
        await self.clock.sleep(dt_s)

    async def wait_until(
        self, predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.1
    ) -> bool:
        """Wait (simulated time) until ``predicate()`` holds; False on timeout."""
        return await self.clock.wait_until(predicate, timeout_s, poll_s)

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        """Events recorded so far whose kind equals or starts with ``kind``."""
        return [e for e in self.events if e["kind"] == kind or e["kind"].startswith(kind + ".")]

    async def navigator_ready(self, timeout_s: float = 10.0) -> Any:
        """The app's navigator, once a pose in ``map`` is published and has settled 0.5 s.

        Raises:
            ScenarioFailed: no navigation stack, or no ``/pose`` within ``timeout_s``.
        """
        nav = self.app.navigator
        if nav is None:
            raise ScenarioFailed("the navigation stack is not built (app.navigator is None)")
        if not await self.wait_until(lambda: self.bus.latest(POSE) is not None, timeout_s, 0.05):
            raise ScenarioFailed(f"no /pose within {timeout_s:g} s: estimation is not running")
        await self.sleep(0.5)
        return _GoalLog(nav, self)

    def truth(self) -> Pose2D | None:
        """The rover's true pose in ``map`` (simulator ground truth)."""
        msg = self.bus.latest(GROUND_TRUTH)
        return msg.pose if msg is not None else None

    def cancel_timers(self) -> None:
        """Cancel scripted events that have not fired."""
        for task in self._timers:
            task.cancel()


class _GoalLog:
    """The navigator as a script sees it: ``send_goal`` and ``cancel`` are also published on
    ``/goal`` (what ``curio replay`` gives the navigator again); the rest is the navigator's."""

    def __init__(self, nav: Any, ctx: ScenarioContext) -> None:
        self._nav = nav
        self._ctx = ctx

    def send_goal(self, poses: Pose2D | list[Pose2D], *, tag: str = "") -> Any:
        """Publish the goal on ``/goal``, then give it to the navigator."""
        seq = (poses,) if isinstance(poses, Pose2D) else tuple(poses)
        self._ctx.bus.publish(GOAL, NavGoal(self._ctx.now(), "send", seq, tag=tag))
        return self._nav.send_goal(poses, tag=tag)

    def cancel(self, reason: str = "canceled") -> None:
        """Publish the cancel on ``/goal``, then cancel."""
        self._ctx.bus.publish(GOAL, NavGoal(self._ctx.now(), "cancel", reason=reason))
        self._nav.cancel(reason)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._nav, name)


class Scenario(ABC):
    """Base class of scenarios; subclasses set ``name`` and implement :meth:`run`."""

    name = ""
    description = ""
    default_duration_s = 600.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """Return the config this scenario runs with (default: unchanged)."""
        return cfg

    def wall_epoch_s(self, cfg: Config) -> float | None:
        """The UNIX time the simulated wall clock starts at (None: the clock's fixed default);
        a scenario set on a given day and time of day overrides it."""
        return None

    @abstractmethod
    async def run(self, ctx: ScenarioContext) -> None:
        """The script. Raise :class:`ScenarioFailed` (or record failed checks) to fail."""


def _apply_common_args(cfg: Config, args: ScenarioArgs) -> Config:
    updates: dict[str, Any] = {}
    sim = cfg.sim.model_copy()
    if args.map_yaml is not None:
        sim.world = str(Path(args.map_yaml).resolve())
    if args.start is not None:
        sim.start = args.start
    if args.seed is not None:
        sim.seed = args.seed
    if args.visitors is not None:
        sim.crowd = sim.crowd.model_copy(update={"visitors": args.visitors})
    updates["sim"] = sim
    record = cfg.record.model_copy()
    record.enabled = args.record is not None  # scenarios record only when asked
    record.file = str(Path(args.record).resolve()) if args.record is not None else None
    updates["record"] = record
    if not args.web:
        web = cfg.web.model_copy()
        web.enabled = False
        updates["web"] = web
    return cfg.model_copy(update=updates)


def _fresh_data_dir(cfg: Config, name: str) -> Config:
    """The config with an emptied data directory of its own for this scenario and seed,
    ``<data_dir>/scenarios/<name>-seed<N>``: a run never depends on what an earlier run (or the
    rover) left there (paths edited on the dashboard, an IMU calibration), and the same seed
    gives the same report."""
    directory = cfg.resolve(cfg.data_dir) / "scenarios" / f"{name}-seed{cfg.sim.seed}"
    shutil.rmtree(directory, ignore_errors=True)
    return cfg.model_copy(update={"data_dir": str(directory)})


async def _collect(ctx: ScenarioContext, metrics: _Metrics, stop: asyncio.Event) -> None:
    """Gather events, the driven path length and the localisation error."""
    events_sub = ctx.bus.subscribe(EVENTS)
    truth_sub = ctx.bus.subscribe(GROUND_TRUTH, maxsize=64)
    pose_sub = ctx.bus.subscribe(POSE, maxsize=64)
    try:
        while not stop.is_set():
            for ev in events_sub.drain():
                ctx.events.append({"t": round(ev.stamp, 3), "kind": ev.kind,
                                   "detail": to_jsonable(ev.detail, 6)})
            for gt in truth_sub.drain():
                if metrics.last_truth is not None:
                    metrics.path_length_m += metrics.last_truth.distance_to(gt.pose)
                metrics.last_truth = gt.pose
                metrics.truth_history.append((gt.stamp, gt.pose))
                if len(metrics.truth_history) > 2000:
                    del metrics.truth_history[:1000]
            for est in pose_sub.drain():
                _score_pose(metrics, est)
            await ctx.clock.sleep(0.05)
    finally:
        for ev in events_sub.drain():
            ctx.events.append({"t": round(ev.stamp, 3), "kind": ev.kind,
                               "detail": to_jsonable(ev.detail, 6)})
        events_sub.close()
        truth_sub.close()
        pose_sub.close()


def _score_pose(metrics: _Metrics, est: PoseWithCovariance) -> None:
    """Compare an estimate with the ground truth at the same stamp (nearest sample)."""
    if not metrics.truth_history:
        return
    hist = metrics.truth_history  # in stamp order
    i = bisect.bisect_left(hist, est.stamp, key=lambda item: item[0])
    best = min(hist[max(0, i - 1):i + 1], key=lambda item: abs(item[0] - est.stamp))
    if abs(best[0] - est.stamp) > 0.05:
        return
    err = est.pose.distance_to(best[1])
    yaw_err = math.remainder(est.pose.yaw - best[1].yaw, 2 * math.pi)
    metrics.sq_err_sum += err * err
    metrics.sq_yaw_err_sum += yaw_err * yaw_err
    metrics.max_err_m = max(metrics.max_err_m, err)
    metrics.err_count += 1


async def run_scenario(
    scenario: Scenario,
    cfg: Config,
    args: ScenarioArgs,
    report_path: Path | None = None,
    on_app: Callable[[App], Awaitable[None]] | None = None,
) -> dict[str, Any]:
    """Run ``scenario`` headless on a simulated clock and return its report.

    Args:
        scenario: what to run.
        cfg: the base config (the scenario and ``args`` adjust it).
        args: ``curio sim`` arguments.
        report_path: where to write the JSON report (atomically), if given.
        on_app: awaited once the app has started (``--web`` uses it to print the URL).
    """
    cfg = _fresh_data_dir(scenario.configure(_apply_common_args(cfg, args), args), scenario.name)
    settle = 3 if driver_mode(cfg).emulated else 0  # pty bytes take a few loop turns
    epoch = scenario.wall_epoch_s(cfg)
    clock = SimClock(speed=args.speed, settle_polls=settle,
                     **({"epoch_wall_s": epoch} if epoch is not None else {}))
    wall_start = wall_perf_counter()
    app = App(cfg, clock, web=args.web)
    ctx = ScenarioContext(app, clock, args)
    metrics = _Metrics()
    duration = args.duration_s if args.duration_s is not None else scenario.default_duration_s
    failure = await _drive(scenario, ctx, metrics, duration, on_app)
    report = _report(scenario, ctx, metrics, failure, wall_start)
    if report_path is not None:
        atomic_write_json(report_path, report)
    return report


async def _drive(scenario: Scenario, ctx: ScenarioContext, metrics: _Metrics, duration: float,
                 on_app: Callable[[App], Awaitable[None]] | None) -> str | None:
    """Start the app, run the script on the simulated clock for at most ``duration`` seconds
    while collecting ground truth, stop the app; return why the run failed (None: it did not)."""
    app, clock = ctx.app, ctx.clock
    failure: str | None = None
    stop_collect = asyncio.Event()
    script_done = False

    async def script() -> None:
        nonlocal failure, script_done
        try:
            await clock.wait_for(scenario.run(ctx), duration)
        except TimeoutError:
            failure = f"scenario did not finish within {duration:g} s of simulated time"
        except ScenarioFailed as exc:
            failure = str(exc)
        finally:
            script_done = True

    await app.start()
    if on_app is not None:
        await on_app(app)
    collector = asyncio.create_task(_collect(ctx, metrics, stop_collect), name="collector")
    script_task = asyncio.create_task(script(), name=f"scenario:{scenario.name}")
    try:
        await clock.run(stop=lambda: script_done or bool(app.failed_parts()))
    finally:
        ctx.cancel_timers()
        crashed = app.failed_parts()
        if crashed and failure is None:
            name, exc = crashed[0]
            failure = f"part {name} crashed: {type(exc).__name__}: {exc}"
        if not script_task.done():
            script_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await script_task
        await _settle_final_events(clock)
        stop_collect.set()
        collector.cancel()  # its clock sleep would never fire: the clock has stopped
        with contextlib.suppress(asyncio.CancelledError):
            await collector
        await app.stop()
    return failure


def _report(scenario: Scenario, ctx: ScenarioContext, metrics: _Metrics, failure: str | None,
            wall_start: float) -> dict[str, Any]:
    """The report of DESIGN.md's contract (see the module docstring)."""
    cfg = ctx.cfg
    failed_checks = [c for c in ctx.checks if not c.ok]
    if failure is None and failed_checks:
        failure = "failed checks: " + ", ".join(c.name for c in failed_checks)
    collisions = sum(1 for e in ctx.events if e["kind"] == "collision")
    loc_on = cfg.localization.enabled and metrics.err_count > 0
    rmse = math.sqrt(metrics.sq_err_sum / metrics.err_count) if loc_on else None
    if loc_on:
        ctx.metrics.setdefault("localization_yaw_rmse_rad",
                               round(math.sqrt(metrics.sq_yaw_err_sum / metrics.err_count), 6))
        ctx.metrics.setdefault("localization_max_error_m", round(metrics.max_err_m, 6))
    return {
        "scenario": scenario.name,
        "seed": cfg.sim.seed,
        "success": failure is None,
        "failure": failure,
        "sim_time_s": round(ctx.clock.now(), 3),
        "wall_time_s": round(wall_perf_counter() - wall_start, 3),
        "goals_reached": ctx.goals_reached,
        "goals_total": ctx.goals_total,
        "collisions": collisions,
        "path_length_m": round(metrics.path_length_m, 4),
        "localization_rmse_m": None if rmse is None else round(rmse, 6),
        "drivers_mode": cfg.drivers.mode,
        "checks": [{"name": c.name, "ok": c.ok, "detail": c.detail} for c in ctx.checks],
        "metrics": to_jsonable(ctx.metrics, 6),
        "events": ctx.events,
    }


async def _settle_final_events(clock: SimClock) -> None:
    """Let already-queued work (final events) run before collecting."""
    for _ in range(5):
        await clock.sleep(0)
