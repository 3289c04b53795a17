"""The composition root: builds every part from the config and runs them in one task group.

Each subsystem has one wiring function that takes its dependencies explicitly, constructs its
objects by constructor injection, registers its running pieces on a
:class:`~curio.core.parts.Parts` registry and returns a typed result: ``build_sim``
(``curio/sim/wiring.py``), ``build_drivers`` (``curio/drivers/wiring.py``),
``build_estimation`` (``curio/estimation/wiring.py``), ``build_safety``
(``curio/safety/wiring.py``), ``build_navigation`` (``curio/nav/wiring.py``),
``build_people`` (``curio/people/wiring.py``),
``build_tours`` (``curio/tours/wiring.py``), ``build_behaviour`` (``curio/bt/wiring.py``),
``build_fleet`` (``curio/fleet/wiring.py``, only with ``fleet.enabled``) and
``build_web`` (``curio/web/wiring.py``); the flight recorder (``build_recorder``,
``curio/record/wiring.py``) comes first, so its bus tap sees every message, then the event log
(``build_eventlog``, ``curio/eventlog/wiring.py``), the loop watch
(:class:`~curio.core.loopwatch.LoopWatch`: a blocked event loop is a fault on ``/health``) and
the run marker (:class:`~curio.core.runmarker.RunMarker`: a start after an unclean stop is
reported) and the command journal (:class:`~curio.eventlog.commands.CommandJournal`: every
command's answer, across restarts). The order of the calls below is the order of
dependencies. Nothing below this module imports it, and nothing is a module-level singleton:
two ``App`` objects can run side by side (tests do).

Shutdown order: the rover is stopped first (a zero velocity goes to the base and the base's
``halt()`` is awaited), then every task is cancelled and each part's ``close()`` runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import gc
import logging
from collections.abc import Awaitable, Callable
from pathlib import Path

from curio.bt.paths import PathManager
from curio.bt.runner import TreeRunner
from curio.bt.wiring import build_behaviour
from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.datanotes import DataNotes
from curio.core.loopwatch import LoopWatch
from curio.core.memory import reserve_heap, tune_allocator
from curio.core.messages import Twist
from curio.core.parts import Part, Parts
from curio.core.runmarker import RunMarker
from curio.core.topics import CMD_VEL, make_bus
from curio.docking.docker import Docker
from curio.docking.home import HomeDock, seed_home
from curio.docking.station import DockShape, stamp_dock
from curio.drivers.base import BaseDriver
from curio.drivers.modes import driver_mode
from curio.drivers.wiring import build_drivers
from curio.estimation.ekf import EkfNode
from curio.estimation.maps import OccupancyGrid
from curio.estimation.wiring import Localiser, MapServer, build_estimation, map_name
from curio.eventlog.commands import CommandJournal
from curio.eventlog.store import EventLog
from curio.eventlog.wiring import build_eventlog
from curio.fleet.transport import Transport
from curio.fleet.wiring import Fleet, build_fleet, dashboard_address
from curio.help.desk import HelpDesk
from curio.help.wiring import build_help
from curio.kernels import use_cache_dir
from curio.maps.control import MapsAccess
from curio.nav.clearance import ClearanceProbe
from curio.nav.controller import LocalController
from curio.nav.costmap import Costmap
from curio.nav.navigator import NavigatorNode
from curio.nav.obstacles import BlockedDetector, ObstacleNode
from curio.nav.planner import GlobalPlanner
from curio.nav.wiring import build_navigation
from curio.people.wiring import People, attach_guide, build_people
from curio.power.monitor import PowerMonitor
from curio.power.wiring import build_power
from curio.record.recorder import Recorder
from curio.record.wiring import build_recorder, recordings_directory
from curio.robot import RobotModel
from curio.safety.stage import SafetyStage
from curio.safety.wiring import build_safety
from curio.sim.wiring import Simulator, build_sim
from curio.sim.world import World
from curio.tours.wiring import Tours, build_tours
from curio.web.services import UnattendedServices
from curio.web.wiring import WebServer, build_web, open_tokens
from curio.zones.service import ZoneService
from curio.zones.wiring import build_zones

__all__ = ["App"]

log = logging.getLogger("curio.app")


class App:
    """Everything that runs on the rover (or in the simulator), wired together.

    ``None`` means that part is not configured (e.g. ``world`` on the real rover, ``ekf`` when
    ``ekf.enabled`` is false, ``web`` without the dashboard).
    """

    def __init__(self, cfg: Config, clock: Clock, *, web: bool | None = None,
                 inputs: Callable[[Bus, Clock, Parts], None] | None = None,
                 fleet_transport: Transport | None = None,
                 maps: MapsAccess | None = None) -> None:
        """Build every part.

        Args:
            web: serve the dashboard (default: ``web.enabled``).
            inputs: instead of the simulator and the device drivers, registers the parts that
                publish the sensor streams (``curio replay``); ``drivers.mode`` must be ``sim``.
            fleet_transport: the fleet's link (default: a Zenoh session from ``[fleet]``; the
                fleet simulator and tests pass their own).
        """
        self.cfg = cfg
        self.clock = clock
        use_cache_dir(cfg)  # numba_cache_dir, before any kernel compiles or loads
        tune_allocator()  # glibc's end state from the start (curio/core/memory.py)
        self.bus: Bus = make_bus()
        # Home is the dock and the start pose: the last waypoint of path 0 (one source of
        # truth, curio/docking/home.py); the robot model carries it to every part.
        paths_file = cfg.data_path(cfg.bt.paths_file)
        fresh = not Path(paths_file).exists()
        paths = PathManager(cfg.bt.paths, paths_file)
        seed_home(paths, cfg, fresh)
        self.home = HomeDock(paths, cfg.dock.staging_distance_m)
        self.robot = dataclasses.replace(RobotModel.from_config(cfg.robot),
                                         home=self.home.pose())
        self._registry = Parts()
        self._tasks: list[asyncio.Task[None]] = []
        self._crashes = 0  # parts whose run raised (their tasks end with the exception)
        reg = self._registry
        self.tokens = open_tokens(cfg, clock)
        self.recorder: Recorder | None = build_recorder(
            cfg, self.bus, clock, reg, self.robot,
            may_drive=lambda presented: self.tokens.permits(presented, "drive"))
        logging_ = build_eventlog(cfg, self.bus, clock, reg)
        self.eventlog: EventLog | None = logging_.log if logging_ else None
        self.power: PowerMonitor = build_power(cfg, self.bus, clock, reg)
        self.help: HelpDesk = build_help(cfg, self.bus, clock, reg)
        self.loopwatch = LoopWatch(self.bus, clock)
        reg.add(Part("loop", run=self.loopwatch.run))
        self.runmarker = RunMarker(cfg.data_path("running.json"), self.bus, clock)
        reg.add(Part("process", run=self.runmarker.run, close=self.runmarker.close))
        self.journal = CommandJournal(self.bus, clock, self.eventlog)
        reg.add(Part("commands", run=self.journal.run, close=self.journal.close))
        if inputs is None:
            sim = build_sim(cfg, self.bus, clock, reg, self.robot)
        elif not driver_mode(cfg).simulated:
            raise ValueError("App(inputs=...) replaces the drivers: drivers.mode must be 'sim'")
        else:
            sim = None
            inputs(self.bus, clock, reg)
        self.world: World | None = sim.world if sim else None
        self.simulator: Simulator | None = sim.simulator if sim else None
        drivers = build_drivers(cfg, self.bus, clock, reg, self.robot, world=self.world,
                                sim_base=sim.base if sim else None)
        self.base: BaseDriver | None = drivers.base
        self.lidar = drivers.lidar
        self.imu = drivers.imu
        self.emulators = drivers.emulators
        amend = None
        if cfg.dock.enabled and not cfg.dock.in_map:
            shape = DockShape.for_footprint(self.robot.footprint)

            def amend(grid: OccupancyGrid) -> OccupancyGrid:
                return stamp_dock(grid, self.robot.home, shape)

        est = build_estimation(cfg, self.bus, clock, reg, self.robot, amend_map=amend)
        self.map_server: MapServer = est.map_server
        self.ekf: EkfNode | None = est.ekf
        self.localizer: Localiser | None = est.localizer
        self.safety: SafetyStage = build_safety(cfg, self.bus, clock, reg, self.robot)
        nav = build_navigation(cfg, self.bus, clock, reg, self.robot, est.map_server.grid)
        self.costmap: Costmap = nav.costmap
        self.planner: GlobalPlanner = nav.planner
        self.controller: LocalController = nav.controller
        self.controller.motion_allowed = self.safety.would_allow  # its manoeuvres ask the stop zone
        self.navigator: NavigatorNode = nav.navigator
        self.obstacles: ObstacleNode = nav.obstacles
        self.blocked: BlockedDetector = nav.obstacles.detector
        self.zones: ZoneService | None = build_zones(
            cfg, self.bus, clock, self.robot, est.map_server.grid, map_name(cfg),
            costmap=nav.costmap, controller=nav.controller, safety=self.safety,
            home=self.home.pose)
        self.docker: Docker | None = None
        if cfg.dock.enabled:
            self.docker = Docker(cfg, self.bus, clock, self.robot, nav.navigator, self.home,
                                 self.safety)
            reg.add(Part("docking", run=self.docker.run))
        self.people: People | None = build_people(cfg, self.bus, clock, reg, self.robot, nav,
                                                  est.map_server.grid, est.localizer)
        self.tours: Tours = build_tours(cfg, self.bus, clock, reg, self.robot,
                                        lambda: est.map_server.grid, paths)
        probe = ClearanceProbe(nav.planner, nav.costmap, self.bus, clock,
                               self.robot.laser_in_base, nav.costmap.inscribed_radius_m)
        behaviour = build_behaviour(cfg, self.bus, clock, reg, nav, paths, self.tours.store,
                                    docker=self.docker, probe=probe)
        self.paths: PathManager = behaviour.paths
        self.tree: TreeRunner = behaviour.tree
        notes = DataNotes(self.bus, clock)
        for restored in (self.tours.store.restored, self.tours.schedules.restored,
                         paths.restored):
            notes.restored(restored)
        notes.reset(paths.load_warning)
        reg.add(Part("data", run=notes.run))
        attach_guide(self.people, behaviour.tree.ctx.follower)
        self.fleet: Fleet | None = build_fleet(
            cfg, self.bus, clock, reg, self.robot, navigator=nav.navigator,
            grid=lambda: est.map_server.grid, tours=self.tours, paths=self.paths,
            world=self.world, tokens=self.tokens, transport=fleet_transport,
            people_stage=self.people.stage if self.people is not None else None,
            zones=self.zones, maps=maps)
        self.web: WebServer | None = None
        self.web_url: str | None = None
        if cfg.web.enabled if web is None else web:
            self.web = build_web(cfg, self.bus, clock, reg, self.robot, self.paths, self.tokens,
                                 part_states=self.part_states, tours=self.tours,
                                 eventlog=self.eventlog,
                                 recordings_dir=recordings_directory(cfg),
                                 unattended=UnattendedServices(
                                     self.home, self.docker, self.zones, self.help,
                                     self.tours.placement),
                                 journal=self.journal, maps=maps)
            self.web_url = self.web.control_url
            if self.fleet is not None:
                self.fleet.bridge.dashboard_url = dashboard_address(cfg, self.web.port)

    @property
    def parts(self) -> list[Part]:
        """Every registered part, in start order."""
        return self._registry.parts

    def add(self, part: Part) -> None:
        """Register one more part (a command's recorder, a scenario's helper) before start."""
        self._registry.add(part)

    async def start(self) -> None:
        """Start every part's task; return at once."""
        self.bus.bind_loop(asyncio.get_running_loop())
        for part in self.parts:
            if part.run is not None:
                task = asyncio.create_task(self._guard(part.run, part.name), name=part.name)
                self._tasks.append(task)
        # Everything built so far (modules, numba's type system, the maps) lives as long as the
        # rover: out of the cyclic collector's sight, a full collection no longer walks ~130 000
        # objects (86 ms of CPU here, ~0.35 s on a Pi 4 core, with the safety stage held).
        gc.freeze()
        reserve_heap()  # the heap's room for the large work still to come (curio/core/memory.py)

    async def _guard(self, run: Callable[[], Awaitable[None]], name: str) -> None:
        try:
            await run()
        except asyncio.CancelledError:
            raise
        except Exception:
            self._crashes += 1
            log.exception("part %s crashed; stopping the rover", name)
            await self.halt()
            raise
        except BaseException:
            self._crashes += 1
            raise

    async def halt(self) -> None:
        """Stop the rover now: zero velocity to the base and every halt hook."""
        self.bus.publish(CMD_VEL, Twist(self.clock.now(), 0.0, 0.0, source="halt"))
        for hook in self._registry.halt_hooks:
            with contextlib.suppress(Exception):
                await hook()

    async def stop(self) -> None:
        """Stop the rover, then cancel every task and close every part."""
        await self.halt()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._tasks.clear()
        for part in reversed(self.parts):
            if part.close is not None:
                with contextlib.suppress(Exception):
                    await part.close()
        gc.unfreeze()  # a rebuilt App (a map switch) must not keep this one's cycles for ever

    def part_states(self) -> dict[str, str]:
        """Each part's task: ``running``, ``crashed: <error>``, ``stopped`` or ``not started``
        (for the dashboard's health panel)."""
        states = {p.name: "not started" for p in self.parts if p.run is not None}
        for task in self._tasks:
            if not task.done():
                state = "running"
            elif task.cancelled():
                state = "stopped"
            elif task.exception() is not None:
                state = f"crashed: {task.exception()!r}"
            else:
                state = "stopped"
            states[task.get_name()] = state
        return states

    def failed_parts(self) -> list[tuple[str, BaseException]]:
        """Parts whose task ended with an exception (cheap while no part has crashed: a
        scenario asks after every step of the simulated clock)."""
        if self._crashes == 0:
            return []
        out = []
        for task in self._tasks:
            if task.done() and not task.cancelled() and task.exception() is not None:
                exc = task.exception()
                assert exc is not None
                out.append((task.get_name(), exc))
        return out
