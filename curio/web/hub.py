"""The WebSocket hub: bus topics out to every browser.

Design (after rosboard's per-client throttling, made safe for a robot):

* The hub holds **one** bus subscription per topic and encodes each message **once**; the frame
  is then offered to every client.
* Each client (a :class:`~curio.web.session.ClientSession`) has a conflating slot per stream
  key (scan, pose, plans, tree, health, ...) that its own sender task flushes at most
  ``rate_hz`` times a second, and an ordered queue for reliable messages (status, progress,
  events, e-stop, acks) that is never dropped. A slow client only delays its own sender: the
  bus and the other clients never wait for it. A client whose reliable backlog exceeds
  ``MAX_BACKLOG`` is disconnected (code 1013); it reconnects and catches up from the state
  snapshot.
* A (re)connecting client first receives a snapshot of the latched state (status, progress,
  e-stop, help state, paths, grids, tree, health, recent events marked as history) and the
  latest binary frames.
* What browsers send in (commands, the initial pose, teleop) is published by
  :class:`~curio.web.control.RoverControl`; when a client goes, the hub tells it, so a client
  that was driving stops the rover. Answers to commands come from the command journal
  (``ANSWERS``), once they are in the event log. Who holds the driving lease is sent to every page
  (``{"t": "lease"}``); who did what arrives as ``operator.*`` events.
* The hub keeps what the pages need to tell the truth: who set and who released the e-stop
  (``estop_log``), the navigator's current goal (from ``nav.goal_*`` events), what blocks the
  rover while it is blocked or asks for help (:mod:`curio.web.blocker`), the health panel with
  every part's age (:mod:`curio.web.liveness`), and each event's wall-clock time.

Frames: see :mod:`curio.web.encode` (and :mod:`curio.web.people` for the people frames). Times
come from the injected clock.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from aiohttp import WSCloseCode, web

from curio.core.bus import Bus, Subscription, Topic
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.jsonable import to_json, to_jsonable
from curio.core.messages import (
    BatteryState,
    BlockedState,
    DriverHealth,
    EStop,
    Event,
    GridMessage,
    LaserScan,
    LocalizationStatus,
    Obstacles,
    Odometry,
    Path,
    PoseWithCovariance,
    Progress,
    StatusText,
    TourState,
    TreeSnapshot,
    Twist,
)
from curio.core.topics import (
    ANSWERS,
    BATTERY,
    BLOCKED,
    CMD_VEL,
    COSTMAP,
    ESTOP,
    EVENTS,
    GROUND_TRUTH,
    HEALTH,
    LOCAL_COSTMAP,
    LOCAL_PLAN,
    LOCALIZATION,
    MAP,
    OBSTACLES,
    ODOM,
    PEOPLE,
    PEOPLE_TRUTH,
    PLAN,
    POSE,
    PROGRESS,
    SCAN,
    STATUS,
    TOUR,
    TREE,
)
from curio.eventlog.commands import ANSWER_KINDS
from curio.robot import RobotModel
from curio.web.blocker import find_blocker
from curio.web.control import RoverControl, map_bounds
from curio.web.encode import (
    FRAME_LOCAL_PLAN,
    FRAME_PLAN,
    FRAME_TRUTH,
    encode_path,
    encode_pose,
    encode_scan,
    grid_meta,
    grid_png,
    path_to_json,
)
from curio.web.liveness import GOAL_OVER, Liveness
from curio.web.people import people_frame, truth_frame
from curio.web.session import ClientSession
from curio.web.tokens import Identity
from curio.web.unattended_frames import UNATTENDED_FRAMES, unattended_frame

__all__ = ["GRID_TOPICS", "Hub"]

log = logging.getLogger("curio.web.hub")

GRID_TOPICS: dict[str, Topic[GridMessage]] = {
    "map": MAP,
    "costmap": COSTMAP,
    "local_costmap": LOCAL_COSTMAP,
}
MAX_BACKLOG = 2000
RECENT_EVENTS = 50
# A pose from POSE is preferred; ODOM stands in when no POSE arrived for this long, seconds.
POSE_STALE_S = 2.0
# Behaviour-tree states in which the rover is no longer waiting for help.
HELP_OVER_STATES = frozenset({"moving", "arrived", "going_home", "idle", "tour"})
# What blocks the rover is recomputed at most this often while it is blocked, seconds.
BLOCKER_PERIOD_S = 0.5


@dataclass
class _Grid:
    """The latest grid of one kind and the hub's version of it."""

    msg: GridMessage
    serial: int
    png: bytes | None = None


class Hub:
    """Fans bus traffic out to WebSocket clients and keeps the latched state for new ones.

    Args:
        cfg: the whole configuration (``cfg.web`` limits, ``cfg.robot`` geometry).
        robot: the robot model (footprint, home, limits in the snapshot; the laser pose).
        clock: the injected clock (rates, stamps).
        bus: the application bus.
        rover: publishes operator input; counts it for the health panel.
        paths: the path manager (``app.paths``) or None when the behaviour tree is not built.
        part_states: the application's task states for the health panel (None in tests).
    """

    def __init__(self, cfg: Config, robot: RobotModel, clock: Clock, bus: Bus,
                 rover: RoverControl, paths: Any = None,
                 part_states: Callable[[], dict[str, str]] | None = None) -> None:
        self.cfg = cfg
        self.robot = robot
        self.clock = clock
        self.bus = bus
        self.rover = rover
        self.paths = paths
        self.clients: set[ClientSession] = set()
        self._ids = itertools.count(1)
        self._latest_frames: dict[str, str | bytes | Callable[[], str | bytes]] = {}
        self.status: StatusText | None = None
        self.progress: Progress | None = None
        self.estop: EStop | None = None
        self.battery: BatteryState | None = None
        self.blocked: BlockedState | None = None
        self.localization: LocalizationStatus | None = None
        self.tree: TreeSnapshot | None = None
        self.tour: TourState | None = None
        self.health: dict[str, DriverHealth] = {}
        self.help: dict[str, Any] = {"active": False, "message": "", "since": None,
                                      "resolved_at": None}
        self.events: deque[dict[str, Any]] = deque(maxlen=RECENT_EVENTS)
        self.grids: dict[str, _Grid] = {}
        # Grid versions start at this hub's start time (ms): a page that reconnects to the App
        # rebuilt on another map (curio/commands/host.py) never takes its grids for the old ones.
        self._grid_serial = itertools.count(int(clock.wall_time() * 1000.0) % 2**40 + 1)
        self._pose_msg: PoseWithCovariance | None = None
        self._pose_stamp_s = -math.inf
        self._odom: Odometry | None = None
        self.system: dict[str, Any] = {}
        self.slow_clients_dropped = 0
        self.liveness = Liveness(cfg, bus, clock, part_states)
        self.estop_log: dict[str, Any] = {"engaged": False, "set_by": None, "set_at": None,
                                          "reason": "", "released_by": None,
                                          "released_at": None}
        self.goal: dict[str, Any] | None = None
        self.blocker: dict[str, Any] | None = None
        self._blocker_s = -math.inf
        self.path_editor = ""
        self.path_last_editor: dict[int, str] = {}
        self._bus_sample: tuple[float, dict[str, int]] | None = None
        self.bus_rates: dict[str, float] = {}
        self._paths_listened = False
        self._subs: list[tuple[Subscription[Any], Callable[[Any], None]]] = []
        rover.on_lease = self._lease_changed
        if paths is not None and hasattr(paths, "add_listener"):
            paths.add_listener(self.broadcast_paths)
            self._paths_listened = True

    # --- lifecycle ----------------------------------------------------------------------------

    def open(self) -> None:
        """Subscribe to every topic now (call before :meth:`run`, so nothing published
        after start-up is missed)."""
        if self._subs:
            return
        self._sub(SCAN, self._on_scan)
        self._sub(POSE, self._on_pose)
        self._sub(ODOM, self._on_odom)
        self._sub(GROUND_TRUTH, self._on_truth)
        self._sub(PLAN, lambda m: self._on_path("plan", m, FRAME_PLAN))
        self._sub(LOCAL_PLAN, lambda m: self._on_path("local_plan", m, FRAME_LOCAL_PLAN))
        self._sub(OBSTACLES, self._on_obstacles)
        self._sub(STATUS, self._on_status)
        self._sub(PROGRESS, self._on_progress)
        if self.rover.journal is not None:
            # The journal republishes an answer once it is in the event log (written ahead):
            # a page is never told an answer that a kill -9 would take back.
            self._sub(EVENTS, self._on_event_not_answer)
            self._sub(ANSWERS, self._on_event)
        else:
            self._sub(EVENTS, self._on_event)
        self._sub(ESTOP, self._on_estop)
        self._sub(TREE, self._on_tree)
        self._sub(HEALTH, self._on_health, maxsize=64)
        self._sub(LOCALIZATION, self._on_localization)
        self._sub(BATTERY, self._on_battery)
        self._sub(BLOCKED, self._on_blocked)
        self._sub(CMD_VEL, self._on_cmd_vel)
        self._sub(TOUR, self._on_tour)
        self._sub(PEOPLE, lambda m: self._stream("people", lambda: people_frame(m)))
        self._sub(PEOPLE_TRUTH, lambda m: self._stream("people_truth", lambda: truth_frame(m)))
        for key, topic in UNATTENDED_FRAMES.items():  # battery, dock, help, zones (issue 11)
            self._sub(topic, self._unattended(key))
        for name, topic in GRID_TOPICS.items():
            self._sub(topic, self._grid_handler(name))

    def _unattended(self, key: str) -> Callable[[Any], None]:
        """A handler offering each message as the ``key`` frame (curio.web.unattended_frames)."""
        return lambda msg: self._stream(key, lambda: unattended_frame(key, msg))

    def _sub(self, topic: Topic[Any], handler: Callable[[Any], None],
             maxsize: int | None = None) -> None:
        self._subs.append((self.bus.subscribe(topic, maxsize=maxsize), handler))

    async def run(self) -> None:
        """Pump every topic into the clients (until cancelled)."""
        self.open()
        try:
            async with asyncio.TaskGroup() as tg:
                for sub, handler in self._subs:
                    tg.create_task(self._pump(sub, handler), name=f"web.pump{sub.topic.name}")
        finally:
            for sub, _ in self._subs:
                sub.close()
            self._subs.clear()

    @staticmethod
    async def _pump(sub: Subscription[Any], handler: Callable[[Any], None]) -> None:
        async for msg in sub:
            try:
                handler(msg)
            except Exception:
                log.exception("web hub: cannot forward a %s message", sub.topic.name)

    async def close(self) -> None:
        """Stop any teleop motion and close every client at once (code 1001: the pages say
        Offline); each close waits at most the socket's own close timeout."""
        clients = list(self.clients)
        for client in clients:
            self.unregister(client)

        async def close_one(client: ClientSession) -> None:
            with contextlib.suppress(Exception):
                await client.ws.close(code=WSCloseCode.GOING_AWAY, message=b"server shutdown")

        if clients:
            await asyncio.gather(*(close_one(c) for c in clients))

    # --- clients ------------------------------------------------------------------------------

    def register(self, ws: web.WebSocketResponse, who: Identity,
                 remote: str = "") -> ClientSession:
        """Add a connected socket; queue the state snapshot and the latest frames for it."""
        web_cfg = self.cfg.web
        client = ClientSession(next(self._ids), ws, who, web_cfg, self.rover, remote)
        self.clients.add(client)
        client.queue(to_json({"t": "hello", "client": client.id,
                              "control": bool(who.permissions),
                              "who": {"name": who.name, "role": who.role,
                                      "permissions": sorted(who.permissions)},
                              "require_token": web_cfg.require_token, "rate_hz": client.rate_hz,
                              "server_time": self.clock.now()}))
        client.queue(to_json({"t": "state", **self.snapshot()}))
        for key, frame in list(self._latest_frames.items()):
            if callable(frame):
                frame = frame()
                self._latest_frames[key] = frame
            client.offer(key, frame)
        return client

    async def close_clients(self, which: Callable[[ClientSession], bool], code: int,
                            message: bytes) -> int:
        """Close every client for which ``which(client)``; return how many."""
        chosen = [c for c in self.clients if which(c)]
        for client in chosen:
            self.unregister(client)
        for client in chosen:
            with contextlib.suppress(Exception):
                await client.ws.close(code=code, message=message)
        return len(chosen)

    def unregister(self, client: ClientSession) -> None:
        """Forget ``client``; if it was driving, stop the rover."""
        client.mark_closed()
        self.clients.discard(client)
        self.rover.release_teleop(client.id, "teleop client disconnected")

    def _reliable(self, payload: dict[str, Any]) -> None:
        if not self.clients:
            return  # the state it carries is kept for the snapshot of the next client
        text = to_json(payload)
        for client in list(self.clients):
            if len(client.reliable) >= MAX_BACKLOG:
                log.warning("web client %d is too slow (%d messages queued); disconnecting",
                            client.id, len(client.reliable))
                self._drop_slow(client)
                continue
            client.queue(text)

    def _stream(self, key: str, make: Callable[[], str | bytes]) -> None:
        """Offer the frame ``make()`` under ``key``; nobody watching ⇒ it is made only when a
        client connects (the dashboard costs almost nothing without viewers)."""
        if not self.clients:
            self._latest_frames[key] = make
            return
        frame = make()
        self._latest_frames[key] = frame
        for client in self.clients:
            client.offer(key, frame)

    def _drop_slow(self, client: ClientSession) -> None:
        self.slow_clients_dropped += 1
        self.unregister(client)
        client.close_soon(WSCloseCode.TRY_AGAIN_LATER, b"client too slow; reconnect to catch up")

    # --- state --------------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """Everything a (re)connecting page needs to show the robot's real state."""
        return {
            "status": to_jsonable(self.status),
            "progress": to_jsonable(self.progress),
            "estop": to_jsonable(self.estop),
            "battery": to_jsonable(self.battery),
            "blocked": to_jsonable(self.blocked),
            "localization": to_jsonable(self.localization),
            "help": dict(self.help),
            "paths": self.paths_json(),
            "grids": {name: self.grid_info(name) for name in self.grids},
            "tree": self.tree_json(),
            "health": self.health_json(),
            "events": list(self.events),
            "lease": self.rover.lease_json(),
            "estop_log": dict(self.estop_log),
            "goal": self.goal,
            "blocker": self.blocker,
            "map_bounds": self._bounds_json(),
            "tour": self.tour_json(),
            "now": self.clock.now(),
            "robot": {
                "footprint": [list(p) for p in self.robot.footprint_points],
                "home": list(self.robot.home.as_tuple()),
                "max_speed_mps": min(self.robot.max_wheel_speed_mps,
                                     self.cfg.nav.safety.max_speed_mps),
                "max_angular_radps": min(self.robot.max_angular_radps,
                                         self.cfg.nav.safety.max_angular_radps),
                "name": self.cfg.robot.name,
                "tree": self.cfg.bt.tree,
                "tour_stops": [{"name": t.name, "x_m": t.x_m, "y_m": t.y_m}
                               for t in self.cfg.bt.tour_stops],
            },
        }

    def _bounds_json(self) -> dict[str, Any] | None:
        bounds = map_bounds(self.bus)
        if bounds is None:
            return None
        x0, x1, y0, y1 = bounds.extent()
        return {"x_min": x0, "x_max": x1, "y_min": y0, "y_max": y1,
                "origin": [bounds.origin.x, bounds.origin.y, bounds.origin.yaw],
                "width_m": bounds.width_m, "height_m": bounds.height_m}

    def wall(self, stamp: float) -> float:
        """The wall-clock time (UNIX s, the injected clock's) of a clock ``stamp``."""
        return self.clock.wall_time() - (self.clock.now() - stamp)

    def paths_json(self) -> list[dict[str, Any]]:
        """The path manager's paths as JSON data (empty when there is no path manager)."""
        if self.paths is None:
            return []
        return [path_to_json(p) for p in self.paths.list_paths()]

    def broadcast_paths(self, what: str = "changed", path_id: int | None = None) -> None:
        """Tell every client the paths changed: ``what`` happened to ``path_id``, by whom."""
        if self.path_editor and path_id is not None:
            self.path_last_editor[path_id] = self.path_editor
        self._reliable({"t": "paths", "paths": self.paths_json(), "change": what,
                        "path_id": path_id, "by": self.path_editor or None})

    def paths_changed(self, what: str = "changed", path_id: int | None = None) -> None:
        """After an edit through the API: broadcast unless the path manager notifies us."""
        if not self._paths_listened:
            self.broadcast_paths(what, path_id)

    def tree_json(self) -> dict[str, Any] | None:
        """The latest tree snapshot as JSON data."""
        if self.tree is None:
            return None
        return {"tick": self.tree.tick, "stamp": self.tree.stamp,
                "nodes": to_jsonable(list(self.tree.nodes)),
                "blackboard": to_jsonable(self.tree.blackboard)}

    def health_json(self) -> dict[str, Any]:
        """Every part with its age, localisation, battery, system figures, bus drop rates."""
        stats = self.bus.stats()
        reliable = {t.name for t in self.bus.topics() if t.kind == "reliable"}
        topics = [{"name": name, "published": s.published, "dropped": s.dropped,
                   "dropped_per_s": self.bus_rates.get(name, 0.0),
                   "reliable": name in reliable}
                  for name, s in sorted(stats.items()) if s.dropped]
        return {
            "now": self.clock.now(),
            "components": self.liveness.entries(),
            "localization": to_jsonable(self.localization),
            "battery": to_jsonable(self.battery),
            "system": dict(self.system),
            "bus": {
                "dropped_total": sum(s.dropped for s in stats.values()),
                "dropped_per_s": round(sum(self.bus_rates.values()), 2),
                "topics": sorted(topics, key=lambda t: -t["dropped_per_s"]),
            },
            "web": {"clients": len(self.clients),
                    "commands": self.rover.commands_published,
                    "teleop_messages": self.rover.teleop_published},
        }

    def sample_rates(self) -> None:
        """Measure bus drop rates and the watched topics' rates (about once a second)."""
        now = self.clock.now()
        dropped = {name: s.dropped for name, s in self.bus.stats().items()}
        if self._bus_sample is not None and now > self._bus_sample[0]:
            t0, before = self._bus_sample
            self.bus_rates = {name: round((n - before.get(name, 0)) / (now - t0), 2)
                              for name, n in dropped.items() if n != before.get(name, 0)}
        self._bus_sample = (now, dropped)
        self.liveness.sample()

    def own_health(self, **extra: float) -> DriverHealth:
        """The dashboard's own health line (clients, traffic, refusals)."""
        sent = sum(c.sent_frames for c in self.clients)
        return DriverHealth(
            self.clock.now(), "web", "ok",
            f"{len(self.clients)} page(s) connected",
            counters={"clients": float(len(self.clients)),
                      "commands": float(self.rover.commands_published),
                      "teleop_messages": float(self.rover.teleop_published),
                      "rejected_messages": float(self.rover.rejected_messages),
                      "slow_clients_dropped": float(self.slow_clients_dropped),
                      "frames_sent_to_connected": float(sent), **extra})

    def publish_health(self) -> None:
        """Offer the merged health panel to every client (called about once a second)."""
        self._stream("health", lambda: to_json({"t": "health", **self.health_json()}))

    def grid_info(self, name: str) -> dict[str, Any] | None:
        """Version and geometry of grid ``name`` (None if none has arrived)."""
        grid = self.grids.get(name)
        if grid is None:
            return None
        return {"name": name, "version": grid.serial, "url": f"/api/{name}.png?v={grid.serial}",
                **grid_meta(grid.msg)}

    def grid_png(self, name: str) -> tuple[bytes, int] | None:
        """The PNG of grid ``name`` and its version, encoded once per version."""
        grid = self.grids.get(name)
        if grid is None:
            return None
        if grid.png is None:
            grid.png = grid_png(grid.msg)
        return grid.png, grid.serial

    # --- bus handlers -------------------------------------------------------------------------

    def _robot_pose(self) -> Pose2D | None:
        """The rover in map: the localised pose, or odometry when no pose is fresh."""
        pose = self.bus.latest(POSE)
        odom = self.bus.latest(ODOM)
        if pose is not None and (odom is None or odom.stamp - pose.stamp <= POSE_STALE_S):
            return pose.pose
        return odom.pose if odom is not None else None

    def _on_scan(self, msg: LaserScan) -> None:
        robot = self._robot_pose()
        if robot is None:
            return
        laser = robot @ self.robot.laser_in_base
        self._stream("scan", lambda: encode_scan(msg, laser))

    def _on_pose(self, msg: PoseWithCovariance) -> None:
        self._pose_msg = msg
        self._pose_stamp_s = msg.stamp
        self._stream("pose", lambda: encode_pose(msg))

    def _on_odom(self, msg: Odometry) -> None:
        self._odom = msg
        if self._pose_msg is None or msg.stamp - self._pose_stamp_s > POSE_STALE_S:
            self._stream("pose", lambda: encode_pose(msg))

    def _on_truth(self, msg: Odometry) -> None:
        self._stream("truth", lambda: encode_pose(msg, FRAME_TRUTH))

    def _on_path(self, key: str, msg: Path, frame_type: int) -> None:
        self._stream(key, lambda: encode_path(msg, frame_type))

    def _on_obstacles(self, msg: Obstacles) -> None:
        self._stream("obstacles", lambda: to_json({"t": "obstacles", "segments": msg.segments,
                                                   "circles": msg.circles}))

    def _on_status(self, msg: StatusText) -> None:
        self.status = msg
        if msg.state == "needs_help" and not self.help["active"]:
            self.help.update(active=True, message=msg.text, since=msg.stamp, resolved_at=None)
        elif msg.state in HELP_OVER_STATES and self.help["active"]:
            # The tree moved on (e.g. the operator sent it home): no stale HELP ME.
            self.help.update(active=False)
        self._update_blocker(force=True)
        self._reliable({"t": "status", "status": to_jsonable(msg), "help": self.help})

    def _on_progress(self, msg: Progress) -> None:
        self.progress = msg
        self._reliable({"t": "progress", "progress": to_jsonable(msg)})

    def _on_event_not_answer(self, msg: Event) -> None:
        if msg.kind not in ANSWER_KINDS:
            self._on_event(msg)

    def _on_event(self, msg: Event) -> None:
        if msg.kind == "help.requested":
            self.help.update(active=True, message=str(msg.detail.get("message", "")),
                             since=msg.stamp, resolved_at=None)
            self._update_blocker(force=True)
        elif msg.kind == "help.resolved":
            self.help.update(active=False, resolved_at=msg.stamp)
        self.liveness.on_event(msg)
        record = {"stamp": msg.stamp, "wall": self.wall(msg.stamp), "kind": msg.kind,
                  "detail": to_jsonable(msg.detail)}
        self.events.append(record)
        self._reliable({"t": "event", "event": record, "help": self.help})
        self._follow_goal(msg)
        single_goal = (msg.kind == "nav.goal_accepted"
                       and str(msg.detail.get("tag", "")).endswith(" goto")) or (
            msg.kind == "bt.command_accepted" and msg.detail.get("action") == "goto")
        if single_goal and self.progress is not None:
            # The rover drives to a single goal: the squares of a path no longer describe it.
            self.progress = None
            self._reliable({"t": "progress", "progress": None})

    def _follow_goal(self, msg: Event) -> None:
        """The navigator's current goal (for the goal marker), from its events."""
        goal_id = msg.detail.get("goal_id")
        if msg.kind == "nav.goal_accepted" and isinstance(msg.detail.get("goal"), list):
            self.goal = {"goal_id": goal_id, "poses": msg.detail["goal"],
                         "tag": str(msg.detail.get("tag", ""))}
        elif msg.kind in GOAL_OVER and self.goal is not None \
                and goal_id == self.goal.get("goal_id"):
            self.goal = None
        else:
            return
        self._reliable({"t": "goal", "goal": self.goal})

    def _on_estop(self, msg: EStop) -> None:
        """Remember who set and who released the e-stop (every page shows both)."""
        was = self.estop.engaged if self.estop is not None else False
        self.estop = msg
        who = msg.source or "unknown"
        log_ = self.estop_log
        if msg.engaged and not was:
            log_.update(engaged=True, set_by=who, set_at=self.wall(msg.stamp),
                        reason=msg.reason, released_by=None, released_at=None)
        elif not msg.engaged and was:
            log_.update(engaged=False, released_by=who, released_at=self.wall(msg.stamp))
        self._reliable({"t": "estop", "estop": to_jsonable(msg), "log": dict(log_)})

    def _lease_changed(self) -> None:
        self._reliable({"t": "lease", "lease": self.rover.lease_json()})

    def _on_tree(self, msg: TreeSnapshot) -> None:
        self.tree = msg
        self._stream("tree", lambda: to_json({"t": "tree", "tree": self.tree_json()}))

    def _on_health(self, msg: DriverHealth) -> None:
        self.health[msg.name] = msg
        self.liveness.on_report(msg)

    def _on_localization(self, msg: LocalizationStatus) -> None:
        self.localization = msg
        self._stream("localization",
                     lambda: to_json({"t": "localization", "localization": msg}))

    def _on_battery(self, msg: BatteryState) -> None:
        self.battery = msg
        self._stream("battery", lambda: to_json({"t": "battery", "battery": msg}))

    def _on_blocked(self, msg: BlockedState) -> None:
        self.blocked = msg
        self._stream("blocked", lambda: to_json({"t": "blocked", "blocked": msg}))
        self._update_blocker()

    def _update_blocker(self, force: bool = False) -> None:
        """While the rover is blocked or asks for help: what is in its way (≤ 2 Hz)."""
        active = bool(self.help["active"]) or (self.blocked is not None and self.blocked.blocked)
        now = self.clock.now()
        if not active:
            if self.blocker is not None:
                self.blocker = None
                self._stream("blocker", lambda: to_json({"t": "blocker", "blocker": None}))
            return
        if not force and now - self._blocker_s < BLOCKER_PERIOD_S:
            return
        self._blocker_s = now
        pose = self._robot_pose()
        self.blocker = find_blocker(self.bus.latest(SCAN), pose, self.bus.latest(PLAN),
                                    self.blocked, self.robot)
        blocker = self.blocker
        self._stream("blocker", lambda: to_json({"t": "blocker", "blocker": blocker}))

    def tour_json(self) -> dict[str, Any] | None:
        """The running tour (``/tour``) with its age in clock seconds, or None."""
        if self.tour is None:
            return None
        return {**to_jsonable(self.tour), "age_s": round(self.clock.now() - self.tour.stamp, 3)}

    def _on_tour(self, msg: TourState) -> None:
        """The tour, its stop, message, next stop and ETA: for the kiosk and the tours card."""
        self.tour = msg
        self._reliable({"t": "tour", "tour": self.tour_json()})

    def _on_cmd_vel(self, msg: Twist) -> None:
        self._stream("cmd_vel", lambda: to_json({"t": "cmd_vel", "linear_mps": msg.linear_mps,
                                                 "angular_radps": msg.angular_radps,
                                                 "source": msg.source}))

    def _grid_handler(self, name: str) -> Callable[[GridMessage], None]:
        def handle(msg: GridMessage) -> None:
            old = self.grids.get(name)
            if old is not None and (
                old.msg is msg
                or (msg.version != 0 and msg.version == old.msg.version
                    and msg.data.shape == old.msg.data.shape)
            ):
                old.msg = msg if old.msg is msg else old.msg
                return
            self.grids[name] = _Grid(msg, next(self._grid_serial))
            self._stream(f"grid:{name}",
                         lambda: to_json({"t": "grid", "grid": self.grid_info(name)}))

        return handle
