"""The fleet manager: discovery, shared tours and schedules, dispatch — one object, a few parts.

:class:`FleetManager` works on any :class:`~curio.fleet.transport.Transport` and the injected
clock, so ``curio fleet run`` (a Zenoh router session, the real clock) and ``curio fleet sim``
(the simulated clock) run the same code.

* **Discovery**: the rovers' liveliness tokens ``curio/*/alive`` and their statuses
  (:class:`~curio.fleet.manager.roster.Roster`); it holds ``curio/@fleet/manager`` itself so
  the rovers can report whether they see it.
* **Shared data**: a :class:`~curio.tours.store.TourStore` and a
  :class:`~curio.tours.schedule.ScheduleStore` in the manager's ``data_dir`` (the same files
  and rules as on a rover, with stops checked on the shared map; schedules may overlap — the
  fleet has several rovers), and the shared map. A tour is distributed to the rover that runs
  it inside its ``start_tour`` command; the rovers' maps are compared by fingerprint (a rover
  whose map differs is flagged, and updated when it is on the same map). Queries:
  ``curio/@fleet/q/tours``, ``q/schedules``, ``q/map``.
* **Dispatch** (:class:`~curio.fleet.manager.dispatch.Dispatcher`): operator and kiosk
  requests and the schedule's starts become jobs; every ``check_period_s`` they are given to
  the best rover and watched.
* **The map** (:class:`~curio.fleet.maps_sync.MapDistributor`, ``distribute_maps``): the
  manager's map file, read again when it changes, pushed to every rover on that map whose
  cells differ (a signed ``set_map``; a busy rover refuses and is asked again).
* **Zones** (:class:`~curio.fleet.zones_sync.ZoneDistributor`, ``distribute_zones``): the
  zones of the shared map, from the manager's zone file, pushed to every rover on that map
  whose zones differ (a signed ``set_zones``).
* **Events missed while a rover was away** are fetched with a query of its recent events
  (``curio/<rover>/q/events``) when it comes back or a gap in its numbering shows.

Every command it sends is signed with the key ``fleet.manager.key_name`` of its keyring; the
rovers check it against their own keys and roles.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.jsonable import to_jsonable
from curio.estimation.maps import OccupancyGrid
from curio.estimation.wiring import map_name, map_path
from curio.fleet import codec
from curio.fleet.auth import CommandSigner, KeyEntry
from curio.fleet.keys import MANAGER_QUERY, MANAGER_TOKEN, rover_key, rover_of
from curio.fleet.manager.dispatch import Dispatcher, Job
from curio.fleet.manager.roster import Roster, RoverState
from curio.fleet.manager.routes import RouteDistances
from curio.fleet.maps_sync import MapDistributor
from curio.fleet.transport import Sample, Transport
from curio.fleet.zones_sync import ZoneDistributor
from curio.robot import RobotModel
from curio.tours.model import TourError
from curio.tours.placement import MapPlacement
from curio.tours.schedule import ScheduleStore
from curio.tours.store import TourStore
from curio.zones.wiring import zone_file

__all__ = ["FleetManager"]

log = logging.getLogger("curio.fleet.manager")

WATCHED = ("status", "pose", "tour", "battery", "plan", "events", "reply")


class FleetManager:
    """The fleet manager (see the module docstring).

    Args:
        cfg: the config (``fleet.manager``, ``tours``, ``data_dir``, the map, ``robot``).
        clock: injected.
        transport: its link (a router session in deployments).
        key: the key it signs commands with.
        expected: rover names it should know of before they appear (for the page).
    """

    def __init__(self, cfg: Config, clock: Clock, transport: Transport, key: KeyEntry,
                 expected: list[str] | None = None) -> None:
        self.cfg = cfg
        self.mcfg = cfg.fleet.manager
        self.clock = clock
        self.transport = transport
        self.signer = CommandSigner(key, clock.wall_time)
        self.robot = RobotModel.from_config(cfg.robot)
        self.roster = Roster()
        shared = map_name(cfg)
        self.maps = MapDistributor(Path(map_path(cfg)), shared, self.roster, self.send,
                                   self._note, self.mcfg.map_resend_s)
        placement = MapPlacement(lambda: self.grid, self.robot.inscribed_radius_m)
        self.tours = TourStore(cfg.data_path(cfg.tours.file), (), placement)
        self.schedules = ScheduleStore(cfg.data_path(cfg.tours.schedules_file),
                                       ZoneInfo(cfg.tours.timezone), lambda _tid: 0.0,
                                       self.tours.schedule_problem, gap_s=0.0)
        for name in expected or []:
            self.roster.get(name)
        self.routes = RouteDistances(self.grid, self.robot.inscribed_radius_m)
        self.dispatcher = Dispatcher(self.mcfg, self.roster, self._distance, self._tour_def,
                                     self.send, self._note)
        self.zones = ZoneDistributor(zone_file(cfg, shared), shared,
                                     self.robot.max_wheel_speed_mps, self.roster, self.send,
                                     self._note)
        self.log: list[dict[str, Any]] = []
        self._tasks: list[asyncio.Task[None]] = []
        self._last_check_wall: float | None = None
        self._fills: list[str] = []
        self.web: Any = None
        self._tours_payload = self._schedules_payload = b""
        self._refresh_snapshots()
        self._declare()

    @property
    def grid(self) -> OccupancyGrid:
        """The shared map (its file, read again when it changes: :attr:`maps`)."""
        return self.maps.grid

    @property
    def map_sha(self) -> str:
        """The shared map's fingerprint."""
        return self.maps.sha

    def _use_map(self) -> None:
        """The map file changed: route distances use the new cells (tour placement and the
        map query read :attr:`grid` and :attr:`maps` themselves; tours already stored keep
        their stops, new and edited ones are checked on it)."""
        self.routes = RouteDistances(self.grid, self.robot.inscribed_radius_m)

    # --- the link ---------------------------------------------------------------------------
    def _declare(self) -> None:
        t = self.transport
        t.watch_liveliness("curio/*/alive", self._on_alive)
        for topic in WATCHED:
            t.subscribe(f"curio/*/{topic}", self._on_sample)
        t.declare_token(MANAGER_TOKEN)
        t.queryable(f"{MANAGER_QUERY}/*", self._respond)

    def _on_alive(self, sample: Sample) -> None:
        name = rover_of(sample.key)
        if name is not None:
            self.roster.get(name).alive = sample.kind == "put"
            self._note("fleet.rover_seen" if sample.kind == "put" else "fleet.rover_gone",
                       {"rover": name})

    def _on_sample(self, sample: Sample) -> None:
        name = rover_of(sample.key)
        if name is None:
            return
        topic = sample.key.split("/", 2)[2]
        try:
            msg = codec.loads(sample.payload)
        except codec.DecodeError:
            return
        now = self.clock.wall_time()
        try:
            if topic == "events":
                self._on_event(name, msg, now)
            elif topic == "reply":
                self.dispatcher.on_reply(name, msg, now)
                self.maps.on_reply(name, msg)
            else:
                self.roster.heard(name, topic, msg, now)
        except (KeyError, TypeError, ValueError):
            log.debug("fleet manager: a malformed %s from %s was dropped", topic, name)

    def _on_event(self, name: str, msg: dict[str, Any], now: float) -> None:
        r = self.roster.get(name)
        gaps = r.gaps
        if self.roster.event(name, msg):
            self.dispatcher.on_event(name, msg, now)
        if r.gaps != gaps and name not in self._fills:
            self._fills.append(name)

    def _respond(self, key: str, params: str) -> list[tuple[str, bytes]]:
        """Answer ``curio/@fleet/q/{tours,schedules,map}`` (Zenoh's thread: snapshots)."""
        out = []
        what = key.rsplit("/", 1)[-1]
        if what in ("tours", "*"):
            out.append((f"{MANAGER_QUERY}/tours", self._tours_payload))
        if what in ("schedules", "*"):
            out.append((f"{MANAGER_QUERY}/schedules", self._schedules_payload))
        if what in ("map", "*"):
            out.append((f"{MANAGER_QUERY}/map", self.maps.payload))
        return out

    def _refresh_snapshots(self) -> None:
        wall = self.clock.wall_time()
        self._tours_payload = codec.dumps({"t": wall, "tours": [
            t.to_json() for t in self.tours.list_tours()]})
        self._schedules_payload = codec.dumps({"t": wall, "schedules": [
            s.to_json() for s in self.schedules.list_schedules()]})

    def send(self, rover: str, cmd: dict[str, Any]) -> None:
        """Sign ``cmd`` for ``rover`` and send it."""
        self.transport.put(rover_key(rover, "cmd"), self.signer.sign(rover, cmd))
        self._note("fleet.command_sent", {"rover": rover, "action": cmd.get("action"),
                                          "request_id": cmd.get("request_id", "")})

    def _note(self, kind: str, detail: dict[str, Any]) -> None:
        self.log.append({"t": round(self.clock.now(), 3), "wall": self.clock.wall_time(),
                         "kind": kind, "detail": to_jsonable(detail, 4)})
        del self.log[:-5000]
        log.info("%s %s", kind, detail)

    # --- dispatch helpers -------------------------------------------------------------------
    def _tour_def(self, tour_id: int) -> dict[str, Any]:
        try:
            return self.tours.get(tour_id).to_json()
        except TourError:
            raise KeyError(tour_id) from None

    def _distance(self, rover: RoverState, tour_id: int) -> float:
        tour = self.tours.get(tour_id)
        if rover.pose is None or not tour.stops:
            return float("inf")
        first = tour.stops[0]
        return self.routes.distance((rover.pose[0], rover.pose[1]), (first.x_m, first.y_m))

    def dispatch_tour(self, tour_id: int, source: str) -> Job:
        """Ask for a run of ``tour_id`` (an operator, a kiosk); it is queued at once.

        Raises:
            TourError: there is no such tour or it has no stops.
        """
        tour = self.tours.get(tour_id)
        if not tour.stops:
            raise TourError(f"Tour {tour.id} ({tour.name}) has no stops.")
        return self.dispatcher.request(tour.id, tour.name, source, self.clock.wall_time())

    @property
    def last_check_wall_s(self) -> float | None:
        """The wall time of the last schedule check (None before the first)."""
        return self._last_check_wall

    def check(self) -> None:
        """One periodic check: who is online, the schedule, the jobs."""
        now = self.clock.wall_time()
        for name in self.roster.update_online(now, self.mcfg.offline_after_s):
            self.dispatcher.rover_back(name, now)
            if name not in self._fills:
                self._fills.append(name)
        if self.mcfg.distribute_maps:
            if self.maps.reload():
                self._use_map()
            self.maps.check(now, self.mcfg.offline_after_s)
        for r in self.roster.rovers.values():
            flag = bool(r.status.get("map")) and r.status.get("map") != self.map_sha
            r.status["map_differs"] = flag
        self._schedule(now)
        self.dispatcher.tick(now)
        if self.mcfg.distribute_zones:
            self.zones.reload()
            self.zones.check(now, self.mcfg.offline_after_s)
        self._refresh_snapshots()

    def _schedule(self, now: float) -> None:
        last = self._last_check_wall if self._last_check_wall is not None else now
        self._last_check_wall = now
        for occ in self.schedules.occurrences(last, now):
            label = occ.local.isoformat(timespec="minutes")
            if now - occ.wall_s > self.mcfg.start_window_s:
                self._note("dispatch.missed", {"tour_id": occ.tour_id, "due": label})
                continue
            try:
                tour = self.tours.get(occ.tour_id)
            except TourError:
                self._note("dispatch.missed", {"tour_id": occ.tour_id, "due": label,
                                               "reason": "the tour no longer exists"})
                continue
            self.dispatcher.request(tour.id, tour.name, f"schedule {label}", now)

    async def _fill_gaps(self) -> None:
        """Fetch the recent events of rovers that came back or whose events have a gap."""
        while self._fills:
            name = self._fills.pop(0)
            samples = await self.clock.offload(self.transport.get,
                                               rover_key(name, "q/events"), 2.0)
            for sample in samples:
                try:
                    events = codec.loads(sample.payload).get("events", [])
                except codec.DecodeError:
                    continue
                now = self.clock.wall_time()
                for ev in events:
                    if isinstance(ev, dict):
                        self._on_event(name, ev, now)

    # --- running ----------------------------------------------------------------------------
    async def _loop(self, period_s: float, phase_s: float, body: Callable[[], Any]) -> None:
        async for _ in self.clock.every(period_s, phase_s=phase_s):
            result = body()
            if inspect.isawaitable(result):
                await result

    async def start(self) -> None:
        """Open the link (if it is not) and start the parts."""
        await self.clock.offload(self.transport.open)
        self._refresh_snapshots()
        self._tasks = [
            asyncio.create_task(self._loop(self.cfg.fleet.pump_period_s, 0.007,
                                           self.transport.pump), name="manager.pump"),
            asyncio.create_task(self._loop(self.mcfg.check_period_s, 0.09, self._check_and_fill),
                                name="manager.check")]
        if self.web is not None:
            await self.web.start()

    async def _check_and_fill(self) -> None:
        self.check()
        if self._fills:
            await self._fill_gaps()

    def failed_parts(self) -> list[tuple[str, BaseException]]:
        """Parts whose task ended with an exception."""
        return [(t.get_name(), t.exception()) for t in self._tasks  # type: ignore[misc]
                if t.done() and not t.cancelled() and t.exception() is not None]

    async def stop(self) -> None:
        """Stop the parts (the link is closed by its owner)."""
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self.web is not None:
            await self.web.stop()

    # --- views ------------------------------------------------------------------------------
    def rovers_json(self) -> list[dict[str, Any]]:
        """Every rover for the page and the API."""
        now = self.clock.wall_time()
        return [r.to_json(now, self.mcfg.offline_after_s)
                for _, r in sorted(self.roster.rovers.items())]

    def summary(self) -> dict[str, Any]:
        """Counts for reports: jobs by state, re-dispatches."""
        states: dict[str, int] = {}
        for j in self.dispatcher.jobs:
            states[j.state] = states.get(j.state, 0) + 1
        return {"jobs": len(self.dispatcher.jobs), "by_state": states,
                "redispatches": self.dispatcher.redispatches}
