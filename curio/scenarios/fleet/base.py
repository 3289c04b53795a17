"""The fleet simulator: N rovers, each its own application with its own link, in one building,
plus (for scenarios that want it) the fleet manager — on one simulated clock.

:func:`run_fleet` builds, for rover ``r<i>``, the whole :class:`~curio.app.App` with
``fleet.enabled``, its own data directory (``<data_dir>/fleet/<scenario>-seed<N>/r<i>``), its
own start and home pose, its own noise seed, and a transport of its own:

* ``transport="zenoh"`` (the default): a Zenoh *client* session per rover connected over the
  loopback to the manager's *router* session — the deployment shape of ``docs/fleet.md``
  shrunk onto one machine. A :class:`~curio.fleet.zenoh_link.DeliveryLedger` makes the run
  reproducible on the simulated clock (every pump first waits until what was sent has
  arrived), and before the clock starts every session hears every other one.
* ``transport="memory"``: an in-process :class:`~curio.fleet.transport.MemoryNetwork`
  (no sockets; the same fleet code; for tests and benchmarks without the extra).

Every rover's world holds the other rovers as bodies (:class:`~curio.fleet.simworld.PeerBodies`,
placed from the other worlds' true poses half a physics step before each step), so they see
each other in their lidars and cannot drive through each other. The people of the default
world are taken out (each world would move its own copy of them differently).

The report: ``scenario``, ``seed``, ``rovers``, ``transport``, ``success``, ``failure``,
``sim_time_s``, ``wall_time_s``, ``collisions`` (all contacts), ``checks``, ``metrics`` (with at
least ``rover_rover_collisions``, ``rover_rover_encounters``, ``longest_standoff_s``,
``standoffs_s``, and per rover ``msgs_per_s`` and ``bytes_per_s`` sent over the link) and
``per_rover``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import secrets
import shutil
from abc import ABC, abstractmethod
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from curio.app import App
from curio.core.bus import Subscription
from curio.core.clock import SimClock, wall_perf_counter
from curio.core.config import Config, PathConfig
from curio.core.fileio import atomic_write_json
from curio.core.geometry import Pose2D
from curio.core.jsonable import to_jsonable
from curio.core.messages import Event, OperatorAction, OperatorCommand
from curio.core.parts import Part
from curio.core.topics import EVENTS, GROUND_TRUTH, OPERATOR
from curio.fleet.auth import FleetKeyring, KeyEntry
from curio.fleet.simworld import PeerBodies
from curio.fleet.transport import MemoryNetwork, MemoryTransport, Transport
from curio.fleet.zenoh_link import (
    DeliveryLedger,
    ZenohSettings,
    ZenohTransport,
    free_local_endpoint,
)

__all__ = ["FleetArgs", "FleetContext", "FleetScenario", "RoverRun", "run_fleet"]

log = logging.getLogger("curio.fleet.sim")

FLEET_KEY = "fleet"
KEPT_EVENTS = ("tour.", "traffic.", "fleet.", "collision", "help.", "nav.goal_", "check",
               "script", "dispatch.")


class FleetScenarioFailed(Exception):
    """Raised by a script to end the fleet scenario as failed, with the reason."""


@dataclass
class FleetArgs:
    """Arguments of ``curio fleet sim``."""

    rovers: int | None = None
    seed: int = 1
    speed: float | None = None
    duration_s: float | None = None
    transport: Literal["zenoh", "memory"] = "zenoh"


@dataclass
class RoverRun:
    """One simulated rover of the fleet."""

    name: str
    index: int
    app: App
    transport: Transport
    bodies: PeerBodies
    events: list[dict[str, Any]] = field(default_factory=list)
    sub: Subscription[Event] | None = None


@dataclass
class _Check:
    name: str
    ok: bool
    detail: str = ""


class FleetContext:
    """What a fleet scenario script works with."""

    def __init__(self, rovers: list[RoverRun], clock: SimClock, manager: Any,
                 args: FleetArgs, cfg: Config, manager_transport: Transport | None = None) -> None:
        self.rovers = rovers
        self.manager_transport = manager_transport
        self.clock = clock
        self.manager = manager
        self.args = args
        self.cfg = cfg
        self.checks: list[_Check] = []
        self.metrics: dict[str, Any] = {}
        self.script_events: list[dict[str, Any]] = []

    def rover(self, name: str) -> RoverRun:
        """The rover called ``name``."""
        return next(r for r in self.rovers if r.name == name)

    def now(self) -> float:
        """Simulated time, seconds."""
        return self.clock.now()

    def record(self, kind: str, **detail: Any) -> None:
        """A scenario event for the report."""
        self.script_events.append({"t": round(self.clock.now(), 3), "rover": "", "kind": kind,
                                   "detail": to_jsonable(detail, 4)})

    def check(self, name: str, ok: bool, detail: str = "") -> bool:
        """Record a named check; a failed one fails the scenario."""
        self.checks.append(_Check(name, bool(ok), detail))
        self.record("check", name=name, ok=bool(ok), detail=detail)
        return bool(ok)

    def press(self, rover: str, action: OperatorAction, **kwargs: Any) -> None:
        """A dashboard button on ``rover`` (an operator command on its bus)."""
        app = self.rover(rover).app
        app.bus.publish(OPERATOR, OperatorCommand(self.clock.now(), action, source="scenario",
                                                  **kwargs))

    async def sleep(self, dt_s: float) -> None:
        """Sleep simulated seconds."""
        await self.clock.sleep(dt_s)

    async def wait_until(self, predicate: Callable[[], bool], timeout_s: float,
                         poll_s: float = 0.2) -> bool:
        """Wait (simulated) until ``predicate()``; False on timeout."""
        return await self.clock.wait_until(predicate, timeout_s, poll_s)

    def cut(self, rover: str) -> None:
        """Cut ``rover``'s link (its session closes, as a pulled access point would)."""
        self.rover(rover).transport.cut()

    def restore(self, rover: str) -> None:
        """Give ``rover`` its link back; with Zenoh, wait until the routes are there again
        (so the run stays reproducible)."""
        t = self.rover(rover).transport
        t.restore()
        if isinstance(t, ZenohTransport) and isinstance(self.manager_transport, ZenohTransport):
            others = [r.transport for r in self.rovers if isinstance(r.transport, ZenohTransport)]
            if not self.manager_transport.sync_routes(others):
                raise FleetScenarioFailed(f"{rover}'s restored session was not heard in 10 s")

    def truth(self, rover: str) -> Pose2D | None:
        """The rover's true pose in ``map``."""
        msg = self.rover(rover).app.bus.latest(GROUND_TRUTH)
        return msg.pose if msg is not None else None

    def collect(self) -> None:
        """Move every rover's new events into its list."""
        for r in self.rovers:
            if r.sub is None:
                continue
            for ev in r.sub.drain():
                r.events.append({"t": round(ev.stamp, 3), "rover": r.name, "kind": ev.kind,
                                 "detail": to_jsonable(ev.detail, 4)})

    def events(self, kind: str, rover: str | None = None) -> list[dict[str, Any]]:
        """Events whose kind is ``kind`` or starts with ``kind.`` (of one rover or all)."""
        self.collect()
        out = [e for r in self.rovers if rover in (None, r.name) for e in r.events
               if e["kind"] == kind or e["kind"].startswith(kind + ".")]
        return sorted(out, key=lambda e: (e["t"], e["rover"]))

    def rover_rover_collisions(self) -> list[dict[str, Any]]:
        """Collision events with another rover's body."""
        out = []
        for r in self.rovers:
            for e in self.events("collision", r.name):
                others = [r.bodies.rover_of(w) for w in e["detail"].get("with", [])]
                if any(o is not None for o in others):
                    out.append({**e, "with_rover": [o for o in others if o]})
        return out

    def standoffs_s(self) -> list[float]:
        """How long each give-way lasted (open ones counted up to now), seconds."""
        out = [float(e["detail"].get("waited_s", 0.0)) for e in self.events("traffic.resume")]
        for r in self.rovers:
            t = r.app.fleet.traffic if r.app.fleet else None
            if t is not None and t.holding and t._holding_since is not None:
                out.append(self.clock.now() - t._holding_since)
        return out


class FleetScenario(ABC):
    """A fleet scenario: starts, per-rover config, the script."""

    name = ""
    description = ""
    default_rovers = 3
    default_duration_s = 600.0
    wants_manager = False

    @abstractmethod
    def starts(self, n: int, seed: int) -> list[tuple[float, float, float]]:
        """Start (and home) poses of the ``n`` rovers, map (m, m, rad)."""

    def configure(self, cfg: Config, args: FleetArgs) -> Config:
        """The config every rover starts from (default: unchanged)."""
        return cfg

    def wall_epoch_s(self, cfg: Config) -> float | None:
        """The simulated wall clock's start (None: the clock's default)."""
        return None

    def tours(self) -> dict[str, list[dict[str, Any]]]:
        """The scenario's tours by name (stops in their JSON form), for the fleet manager."""
        return {}

    def make_manager(self, cfg: Config, clock: SimClock, transport: Transport,
                     key: KeyEntry, rovers: list[str]) -> Any:
        """The fleet manager (only when ``wants_manager``)."""
        from curio.fleet.manager.service import FleetManager

        return FleetManager(cfg, clock, transport, key, expected=rovers)

    @abstractmethod
    async def run(self, ctx: FleetContext) -> None:
        """The script (raise :class:`FleetScenarioFailed` or record failed checks to fail)."""


def _root(cfg: Config, name: str, seed: int) -> Path:
    root = cfg.resolve(cfg.data_dir) / "fleet" / f"{name}-seed{seed}"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True, exist_ok=True)
    return root


def _rover_cfg(base: Config, root: Path, name: str, index: int,
               start: tuple[float, float, float], seed: int) -> Config:
    """Rover ``name``'s config: its name, home (``robot.home`` and the Home path that Go Home
    drives to) and start, noise seed and data directory."""
    robot = base.robot.model_copy(update={"name": name, "home": start})
    home = PathConfig(name="Home", points=[(start[0], start[1])],
                      yaw_deg=[math.degrees(start[2])])
    bt = base.bt.model_copy(update={"paths": [home, *base.bt.paths[1:]]})
    sim = base.sim.model_copy(update={"start": start, "seed": seed * 100 + index})
    fleet = base.fleet.model_copy(update={"enabled": True, "rover": name})
    web = base.web.model_copy(update={"enabled": False})
    record = base.record.model_copy(update={"enabled": False})  # as curio sim: only if asked
    return base.model_copy(update={"robot": robot, "sim": sim, "fleet": fleet, "web": web,
                                   "bt": bt, "record": record, "data_dir": str(root / name)})


def _transports(names: list[str], kind: str) -> tuple[Transport, list[Transport],
                                                      DeliveryLedger | None]:
    """The manager's transport, one per rover, and the ledger (Zenoh only)."""
    if kind == "memory":
        net = MemoryNetwork()
        return (MemoryTransport("manager", net),
                [MemoryTransport(n, net) for n in names], None)
    ledger = DeliveryLedger()
    endpoint = free_local_endpoint()
    manager = ZenohTransport("manager", ZenohSettings("router", listen=(endpoint,)),
                             ledger=ledger)
    rovers: list[Transport] = [ZenohTransport(n, ZenohSettings("client", connect=(endpoint,)),
                                              ledger=ledger) for n in names]
    return manager, rovers, ledger


def _build_rovers(scenario: FleetScenario, base: Config, root: Path, clock: SimClock,
                  args: FleetArgs, transports: list[Transport], key: KeyEntry) -> list[RoverRun]:
    n = len(transports)
    starts = scenario.starts(n, args.seed)
    rovers = []
    for i, transport in enumerate(transports):
        name = transport.name
        cfg = _rover_cfg(base, root, name, i, starts[i], args.seed)
        FleetKeyring(cfg.data_path(cfg.fleet.keys_file)).add(key.name, key.role, key.secret)
        app = App(cfg, clock, web=False, fleet_transport=transport)
        assert app.world is not None and app.fleet is not None
        for pid in list(app.world.people):
            app.world.remove_object(pid)
        rovers.append(RoverRun(name, i, app, transport, PeerBodies(app.world, app.robot)))
    for r in rovers:
        _couple(r, rovers, clock)
    return rovers


def _couple(me: RoverRun, rovers: list[RoverRun], clock: SimClock) -> None:
    """Place the other rovers in ``me``'s world half a physics step before each step."""
    others = [r for r in rovers if r is not me]
    dt = 1.0 / me.app.cfg.sim.physics_rate_hz

    async def sync() -> None:
        for r in others:
            assert r.app.world is not None
            me.bodies.place(r.name, r.app.world.truth_pose)
        async for _ in clock.every(dt, phase_s=0.5 * dt):
            for r in others:
                assert r.app.world is not None
                me.bodies.place(r.name, r.app.world.truth_pose)

    me.app.add(Part("fleet.sim.bodies", run=sync))


async def run_fleet(scenario: FleetScenario, cfg: Config, args: FleetArgs,
                    report_path: Path | None = None) -> dict[str, Any]:
    """Run ``scenario`` with ``args`` on one simulated clock; return (and write) the report."""
    n = args.rovers or scenario.default_rovers
    base = scenario.configure(cfg, args)
    root = _root(base, scenario.name, args.seed)
    epoch = scenario.wall_epoch_s(base)
    clock = SimClock(speed=args.speed) if epoch is None else \
        SimClock(speed=args.speed, epoch_wall_s=epoch)
    wall_start = wall_perf_counter()
    names = [f"r{i + 1}" for i in range(n)]
    mgr_t, rover_ts, ledger = _transports(names, args.transport)
    key = KeyEntry(FLEET_KEY, "operator", secrets.token_urlsafe(24))
    rovers = _build_rovers(scenario, base, root, clock, args, rover_ts, key)
    manager = None
    if scenario.wants_manager:
        mcfg = base.model_copy(update={"data_dir": str(root / "manager")})
        manager = scenario.make_manager(mcfg, clock, mgr_t, key, names)
    ctx = FleetContext(rovers, clock, manager, args, base, mgr_t)
    failure = await _drive(scenario, ctx, mgr_t, ledger,
                           args.duration_s or scenario.default_duration_s)
    report = _report(scenario, ctx, failure, wall_start, ledger)
    if report_path is not None:
        atomic_write_json(report_path, report)
    return report


async def _open_all(ctx: FleetContext, mgr_t: Transport, ledger: DeliveryLedger | None) -> None:
    """Open the manager's link first (the router), then the rovers'; wait for the routes."""
    mgr_t.open()
    for r in ctx.rovers:
        r.transport.open()
    if ledger is not None and isinstance(mgr_t, ZenohTransport):
        zs = [r.transport for r in ctx.rovers if isinstance(r.transport, ZenohTransport)]
        if not mgr_t.sync_routes(zs):
            raise FleetScenarioFailed("the Zenoh sessions did not hear each other within 10 s")


async def _outcome(clock: SimClock, script: Coroutine[Any, Any, None],
                   duration: float) -> str | None:
    """Run ``script`` for at most ``duration`` simulated seconds; why it failed, or None."""
    try:
        await clock.wait_for(script, duration)
    except TimeoutError:
        return f"the scenario did not finish within {duration:g} s of simulated time"
    except FleetScenarioFailed as exc:
        return str(exc)
    return None


async def _drive(scenario: FleetScenario, ctx: FleetContext, mgr_t: Transport,
                 ledger: DeliveryLedger | None, duration: float) -> str | None:
    """Start everything, run the script for at most ``duration`` simulated seconds, stop."""
    clock = ctx.clock
    failure: str | None = None
    done = False

    async def script() -> None:
        nonlocal failure, done
        failure = await _outcome(clock, scenario.run(ctx), duration)
        done = True

    for r in ctx.rovers:
        r.sub = r.app.bus.subscribe(EVENTS)
    try:
        await _open_all(ctx, mgr_t, ledger)
    except FleetScenarioFailed as exc:
        return str(exc)
    for r in ctx.rovers:
        await r.app.start()
    if ctx.manager is not None:
        await ctx.manager.start()
    task = asyncio.create_task(script(), name=f"fleet:{scenario.name}")

    def crashed() -> list[tuple[str, BaseException]]:
        return [f for r in ctx.rovers for f in r.app.failed_parts()] + (
            ctx.manager.failed_parts() if ctx.manager is not None else [])

    try:
        await clock.run(stop=lambda: done or bool(crashed()))
    finally:
        if crashed() and failure is None:
            part, error = crashed()[0]
            failure = f"part {part} crashed: {type(error).__name__}: {error}"
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        ctx.collect()
        await _stop_all(ctx, mgr_t)
    return failure


async def _stop_all(ctx: FleetContext, mgr_t: Transport) -> None:
    if ctx.manager is not None:
        await ctx.manager.stop()
    for r in ctx.rovers:
        await r.app.stop()
    for r in ctx.rovers:
        r.transport.close()
    mgr_t.close()


def link_rates(ctx: FleetContext) -> list[dict[str, Any]]:
    """Messages and bytes each rover sent over its link, per simulated second, by topic."""
    t = max(ctx.clock.now(), 1e-9)
    out = []
    for r in ctx.rovers:
        s = r.transport.stats
        totals = s.totals()
        out.append({"rover": r.name, "msgs_per_s": round(totals["out_msgs"] / t, 2),
                    "bytes_per_s": round(totals["out_bytes"] / t, 1),
                    "in_msgs_per_s": round(totals["in_msgs"] / t, 2),
                    "in_bytes_per_s": round(totals["in_bytes"] / t, 1),
                    "dropped": s.dropped,
                    "by_topic_bytes_per_s": {k: round(v / t, 1)
                                             for k, v in sorted(s.out_bytes.items())}})
    return out


def _report(scenario: FleetScenario, ctx: FleetContext, failure: str | None,
            wall_start: float, ledger: DeliveryLedger | None) -> dict[str, Any]:
    failed = [c for c in ctx.checks if not c.ok]
    if failure is None and failed:
        failure = "failed checks: " + ", ".join(c.name for c in failed)
    rr = ctx.rover_rover_collisions()
    stand = ctx.standoffs_s()
    ctx.metrics.setdefault("rover_rover_collisions", len(rr))
    ctx.metrics.setdefault("rover_rover_encounters", len(ctx.events("traffic.yield")))
    ctx.metrics.setdefault("longest_standoff_s", round(max(stand, default=0.0), 2))
    ctx.metrics.setdefault("standoffs_s", [round(s, 2) for s in stand])
    ctx.metrics.setdefault("link", link_rates(ctx))
    if ledger is not None:
        ctx.metrics.setdefault("delivery_timeouts", ledger.timeouts)
    managed = [{"t": e["t"], "rover": "manager", "kind": e["kind"], "detail": e["detail"]}
               for e in (ctx.manager.log if ctx.manager is not None else [])
               if e["kind"].startswith(("dispatch.", "fleet.rover_"))]
    events = sorted([e for r in ctx.rovers for e in r.events
                     if e["kind"].startswith(KEPT_EVENTS)] + ctx.script_events + managed,
                    key=lambda e: (e["t"], e["rover"], e["kind"]))
    return {
        "scenario": scenario.name, "seed": ctx.args.seed, "rovers": len(ctx.rovers),
        "transport": ctx.args.transport, "success": failure is None, "failure": failure,
        "sim_time_s": round(ctx.clock.now(), 3),
        "wall_time_s": round(wall_perf_counter() - wall_start, 3),
        "collisions": sum(len(ctx.events("collision", r.name)) for r in ctx.rovers),
        "checks": [{"name": c.name, "ok": c.ok, "detail": c.detail} for c in ctx.checks],
        "metrics": to_jsonable(ctx.metrics, 6),
        "per_rover": [_rover_summary(ctx, r) for r in ctx.rovers],
        "events": events,
    }


def _rover_summary(ctx: FleetContext, r: RoverRun) -> dict[str, Any]:
    t = r.app.fleet.traffic if r.app.fleet else None
    truth = ctx.truth(r.name)
    return {"rover": r.name,
            "tours_completed": len(ctx.events("tour.finished", r.name)),
            "encounters": len(ctx.events("traffic.yield", r.name)),
            "longest_wait_s": round(t.longest_wait_s, 2) if t else 0.0,
            "collisions": len(ctx.events("collision", r.name)),
            "final_pose": None if truth is None else [round(truth.x, 3), round(truth.y, 3),
                                                     round(truth.yaw, 3)],
            "distance_home_m": None if truth is None else round(
                math.hypot(truth.x - r.app.robot.home.x, truth.y - r.app.robot.home.y), 3)}
