"""The soak's rover: the whole application in emulated mode on a simulated clock, one process
that the orchestrator may kill (``python -m curio.soak.rover SPEC.json``).

The spec (JSON, written by the orchestrator) gives: the config file and overrides, the boot
number, where the simulated clock starts (``start_sim_s``) and the building's clock at that
moment (``start_wall_s``), where the simulated rover stands (``truth``: ``sim.start``) and its
battery, when the soak ends (``end_wall_s``), the faults still to come, the restart fault to
judge (``restart``), the ballast file for the disk-full faults, and the seed.

What the rover knows comes from its data directory only: its own pose estimate starts from
what it persisted (``last_pose.json``), not from the simulator.

It starts as ``curio run`` does: the compiled kernels loaded (or compiled) before the
application is built (:func:`curio.commands.warmup.prepare`), so a kernel that still compiles
while the rover runs is a warning in its log.

Parts added beside the application's: the fault runner (:mod:`curio.soak.judge`), the
director (the time-lapse while parked, the end), a heartbeat with the simulated rover's state,
a forwarder of the events the ledger needs, and a resource probe (:mod:`curio.soak.probes`).
The process exits 0 after a clean end, 1 when a part of the application crashed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import sys
from pathlib import Path
from typing import Any

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import load_config
from curio.core.geometry import Pose2D
from curio.core.messages import Event
from curio.core.topics import ANSWERS, ESTOP, EVENTS, LOCALIZATION, OPERATOR, POSE, STATUS, TOUR
from curio.eventlog.commands import ANSWER_KINDS
from curio.soak.day import Building, SoakHooks
from curio.soak.faults import Targets
from curio.soak.judge import FaultRunner
from curio.soak.link import BEAT_S, Link
from curio.soak.plan import PlannedFault
from curio.soak.probes import CycleTimer, RateWatch, resources

__all__ = ["FORWARDED", "main", "run_rover"]

log = logging.getLogger("curio.soak.rover")

RES_S = 60.0
DIRECTOR_S = 1.0
FORWARDED = ("bt.command_", "tour.", "collision", "help.", "system.", "data.", "loop.",
             "safety.estop", "driver.", "localization.", "eventlog.", "battery.",
             "nav.goal_rejected", "operator.", "dock.")


class Rover:
    """The application plus the soak's parts (see the module docstring)."""

    def __init__(self, spec: dict[str, Any], hooks: SoakHooks | None = None) -> None:
        self.spec = spec
        cfg = load_config(spec.get("config"), list(spec.get("overrides", [])))
        self.clock = SimClock(speed=None, start_s=float(spec["start_sim_s"]),
                              epoch_wall_s=float(spec["start_wall_s"]), settle_polls=3)
        self.app = App(cfg, self.clock, web=True)
        self.link = Link(boot=int(spec.get("boot", 0)))
        self.hooks = hooks or SoakHooks()
        self.building = Building(self.app, self.hooks)
        ballast = spec.get("ballast")
        plan = [PlannedFault.from_json(f) for f in spec.get("faults", [])]
        self.runner = FaultRunner(self.app, self.clock, self.link, plan,
                                  Targets.of(self.app, self.clock,
                                             Path(ballast) if ballast else None))
        self.end_wall_s = float(spec["end_wall_s"])
        self.stop_requested = False
        self.done = False
        self.lapsed_s = float(spec.get("lapsed_s", 0.0))
        self.nav_timer = CycleTimer(self.app.navigator, "step")
        self.safety_rate = RateWatch(cfg.nav.safety.rate_hz)
        self.safety_timer = CycleTimer(self.app.safety, "step", self.safety_rate.on_step,
                                       self.clock.now)
        self.runner.on_stall = self.safety_rate.excuse
        # subscribed before the application starts: what it says while starting (an unclean
        # restart, a restored data file, an interrupted tour) must reach the orchestrator too
        self._ops = self.app.bus.subscribe(OPERATOR)
        self._events = self.app.bus.subscribe(EVENTS)
        self._answers = self.app.bus.subscribe(ANSWERS)
        battery = spec.get("battery_v")
        if battery is not None and self.app.world is not None:
            self.app.world.set_battery_voltage(float(battery))

    # --- parts --------------------------------------------------------------------------------

    async def beat(self) -> None:
        """Report the simulated rover's state every ``BEAT_S``."""
        bus, world = self.app.bus, self.app.world
        assert world is not None  # emulated mode: the simulator's world feeds the emulators
        async for now in self.clock.every(BEAT_S, immediate=True):
            truth = world.truth_pose
            v, w = world.truth_twist
            tour, status, estop = bus.latest(TOUR), bus.latest(STATUS), bus.latest(ESTOP)
            loc, pose = bus.latest(LOCALIZATION), bus.latest(POSE)
            self.link.send(
                "beat", sim_s=now, wall_s=self.clock.wall_time(),
                truth=[truth.x, truth.y, truth.yaw], v_mps=v, w_radps=w,
                battery_v=world.battery_voltage(), collisions=world.collisions,
                tour=tour.tour_id if tour is not None else None,
                status=status.state if status is not None else None,
                estop=bool(estop.engaged) if estop is not None else None,
                estop_source=estop.source if estop is not None else None,
                loc=loc.state if loc is not None else None,
                pose=[pose.pose.x, pose.pose.y, pose.pose.yaw] if pose is not None else None,
                lapsed_s=self.lapsed_s, **self.runner.describe())

    async def forward(self) -> None:
        """Send the events and operator commands the orchestrator's ledger needs."""
        ops, events, answers = self._ops, self._events, self._answers

        async def commands() -> None:
            async for cmd in ops:
                self.link.send("ev", kind="operator", sim_s=cmd.stamp,
                               wall_s=self.clock.wall_time(), detail={
                                   "action": cmd.action, "request_id": cmd.request_id,
                                   "source": cmd.source})

        def send(ev: Event) -> None:
            self.link.send("ev", kind=ev.kind, sim_s=ev.stamp, wall_s=self.clock.wall_time(),
                           detail=ev.detail)

        async def others() -> None:
            async for ev in events:
                if ev.kind.startswith(FORWARDED) and ev.kind not in ANSWER_KINDS:
                    send(ev)

        async def given() -> None:  # the answers the rover gave: once in its event log
            async for ev in answers:
                send(ev)

        try:
            await asyncio.gather(commands(), others(), given())
        finally:
            ops.close()
            events.close()
            answers.close()

    async def probe(self) -> None:
        """A resource and timing sample every ``RES_S`` (and a first one at once)."""
        async for now in self.clock.every(RES_S, immediate=True):
            self.sample(now)

    def sample(self, now: float) -> None:
        """One resource and timing sample (simulated seconds ``now``)."""
        self.link.send("res", sim_s=now, wall_s=self.clock.wall_time(),
                       **resources(self.app), nav=self.nav_timer.take(),
                       safety=self.safety_timer.take(), safety_rate=self.safety_rate.take(now))

    async def direct(self) -> None:
        """Say when the building's clock reaches ``end_wall_s`` (then keep running until the
        orchestrator stops the rover); time-lapse while the rover is parked."""
        async for _ in self.clock.every(DIRECTOR_S):
            if self.stop_requested:
                return
            wall = self.clock.wall_time()
            if wall >= self.end_wall_s:
                if not self.done:
                    self.done = True
                    self.runner.plan.clear()  # no fault after the end: the soak is closing
                    self.link.send("end", sim_s=self.clock.now(), wall_s=wall)
                continue
            if not self.building.parked(self.runner.busy):
                continue
            nexts = [self.end_wall_s]
            due = self.runner.next_due_wall_s()
            if due is not None:
                nexts.append(due)

            def jumped(gap: float) -> None:
                self.lapsed_s += gap

            self.building.lapse(self.clock, wall, nexts, jumped)

    async def listen(self) -> None:
        """Read the orchestrator's lines on standard input (``stop``; end of file: the
        orchestrator is gone, stop too)."""
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
        while True:
            line = await reader.readline()
            if not line:  # the orchestrator is gone: stop cleanly rather than run orphaned
                self.stop_requested = True
                return
            with contextlib.suppress(ValueError):
                if json.loads(line).get("t") == "stop":
                    self.stop_requested = True
                    return

    # --- life ---------------------------------------------------------------------------------

    async def _guarded(self, part: Any) -> None:
        """Run one of the soak's own parts; a crash is reported to the orchestrator (a bug in
        the soak, not in the rover) and the rover goes on."""
        try:
            await part()
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("soak part %s crashed", part.__name__)
            self.link.send("soak_error", part=part.__name__,
                           error=f"{type(exc).__name__}: {exc}")

    def _judge_restart(self) -> None:
        restart = self.spec.get("restart")
        if not restart:
            return
        fault = PlannedFault.from_json(restart["fault"])
        health = ("process", "data") if fault.kind == "corrupt_file" else ("process",)
        kinds = ("system.unclean_restart", "tour.interrupted", "data.restored", "data.reset")
        self.runner.judge_restart(fault, float(restart["killed_sim_s"]),
                                  float(restart["killed_wall_s"]), health, kinds)

    async def run(self) -> int:
        """Run until the end, a stop request or a crashed part; return the exit code."""
        app = self.app
        authored = self.building.author()
        self._judge_restart()
        await app.start()
        self.hooks.on_start(app)
        web = app.web
        self.link.send("hello", port=web.port if web is not None else None, pid=_pid(),
                       sim_s=self.clock.now(), wall_s=self.clock.wall_time(), authored=authored,
                       start_pose=_pose_list(getattr(app.localizer, "start", None)))
        tasks = [asyncio.create_task(self._guarded(coro), name=f"soak.{coro.__name__}")
                 for coro in (self.runner.run, self.beat, self.forward, self.probe)]
        director = asyncio.create_task(self.direct(), name="soak.director")
        listener = asyncio.create_task(self.listen(), name="soak.listen")
        await self.clock.run(stop=lambda: director.done() or bool(app.failed_parts()))
        crashed = app.failed_parts()
        if not crashed:
            self.sample(self.clock.now())  # the last window's timing, however short the run
        for task in (*tasks, listener):
            task.cancel()
        for task in (*tasks, listener):
            with contextlib.suppress(BaseException):
                await task
        self.link.send("done" if self.done else "stopped", sim_s=self.clock.now(),
                       wall_s=self.clock.wall_time(),
                       crashed=[f"{n}: {type(e).__name__}: {e}" for n, e in crashed])
        await app.stop()
        return 1 if crashed else 0


def _pid() -> int:
    import os

    return os.getpid()


def _pose_list(pose: Pose2D | None) -> list[float] | None:
    return None if pose is None else [pose.x, pose.y, pose.yaw]


async def run_rover(spec: dict[str, Any]) -> int:
    """Build the rover from ``spec`` and run it."""
    return await Rover(spec).run()


def main(argv: list[str] | None = None) -> int:
    """``python -m curio.soak.rover SPEC.json``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m curio.soak.rover SPEC.json", file=sys.stderr)
        return 2
    spec = json.loads(Path(args[0]).read_text(encoding="utf-8"))
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
                        datefmt="%H:%M:%S")
    # As ``curio run`` starts: the compiled kernels loaded (or compiled) first, and a kernel
    # that still compiles inside the running loop named in the log.
    from curio.commands.warmup import config_args, prepare

    config = spec.get("config")
    overrides = list(spec.get("overrides", []))
    prepare(load_config(config, overrides), config_args(config, overrides))
    return asyncio.run(run_rover(spec))


if __name__ == "__main__":
    sys.exit(main())
