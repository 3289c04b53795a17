"""The rover's bridge to the fleet: selected topics out, signed commands in, queryables.

Out, under ``curio/<rover>/`` (JSON unless said; :mod:`curio.fleet.codec`):

* ``pose`` — ``/pose`` (map) with the speed from ``/odom``, at ``pose_rate_hz``;
* ``traffic`` — pose, speed, the plan ahead and the right-of-way state (``traffic.py``), at
  ``pose_rate_hz`` while the rover has a goal, 1/``IDLE_EVERY`` of that without;
* ``status`` — state and text, e-stop, localisation, goal, tour, battery, ready (and why
  not), home, the map's fingerprint, the link; the power model's state of charge, level,
  charging and time left (``/power``), the dock (``/dock``: None when no dock is fitted) and
  the rover's dashboard address (``fleet.dashboard_url``); every ``status_period_s``;
* ``battery``, ``plan`` (thinned to ``plan_step_m``), ``tour`` (the kiosk's state) — when
  they change;
* ``events`` — every ``/events`` event, numbered, as it comes;
* ``health`` — every component's state from ``/health``, every ``health_period_s``;
* ``scan`` — the scan thinned to ``scan_beams`` (binary), at ``scan_rate_hz``;
* ``reply`` — the outcome of each command.

In: ``curio/<rover>/cmd`` — a signed envelope (:mod:`curio.fleet.auth`), verified with the
rover's own keys, then run by :class:`~curio.fleet.commands.CommandExecutor`. A refused
command changes nothing; the reply and a ``fleet.command_refused`` event say why.

Queries (``get``): ``curio/<rover>/q/map`` (binary map), ``q/paths``, ``q/tours``, ``q/plan``,
``q/events`` (the last tour and command events, for a manager that missed them);
answered on Zenoh's thread from snapshots the loop refreshes, so a query never waits for the
loop and the loop never waits for a query.

The rover holds the liveliness token ``curio/<rover>/alive``. **A lost link changes nothing
on the rover except that it is reported**: ``fleet.link_lost`` / ``fleet.link_restored``
events and the ``fleet`` health line; tours, goals and the safety stage carry on, the traffic
rule falls back to the lidar for rovers it no longer hears, and puts are dropped (counted)
rather than queued. The session is opened off the loop (``clock.offload``) and retried.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections import deque
from collections.abc import Callable
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.jsonable import to_jsonable
from curio.core.messages import DriverHealth, Event
from curio.core.topics import (
    BATTERY,
    DOCK,
    ESTOP,
    EVENTS,
    GROUND_TRUTH,
    HEALTH,
    LOCALIZATION,
    MAP,
    ODOM,
    PLAN,
    POSE,
    POWER,
    SCAN,
    STATUS,
    TOUR,
)
from curio.fleet import codec
from curio.fleet.auth import CommandRefused, CommandVerifier
from curio.fleet.commands import CommandExecutor, Outcome
from curio.fleet.keys import MANAGER_TOKEN, keyexpr_intersects, rover_key, rover_of
from curio.fleet.traffic import TrafficNode
from curio.fleet.transport import Sample, Transport
from curio.fleet.zenoh_link import FleetSetupError
from curio.robot import RobotModel
from curio.tours.scheduler import readiness

__all__ = ["FleetBridge", "QuerySnapshots"]

log = logging.getLogger("curio.fleet.bridge")

OPEN_RETRY_S = 5.0
# Events the fleet manager must not miss: kept for ``q/events`` (fetched after an outage).
RECALLED = ("tour.", "bt.command_", "fleet.command")
RECALL_EVENTS = 64
# A rover without a goal sends its traffic message every this many ticks (1 Hz at 5 Hz):
# every rover of a site receives every other's, so the idle ones keep quiet.
IDLE_EVERY = 5
PeerHandler = Callable[[str, dict[str, Any]], None]


class QuerySnapshots:
    """The queryables' answers: immutable bytes per name, swapped in by the loop and read by
    the transport's thread (a dict is replaced whole, never changed in place)."""

    def __init__(self, rover: str) -> None:
        self.rover = rover
        self._data: dict[str, bytes] = {}

    def set(self, what: str, payload: bytes) -> None:
        """Replace the answer for ``q/<what>``."""
        self._data = {**self._data, what: payload}

    def get(self, what: str) -> bytes | None:
        """The answer for ``q/<what>``, or None."""
        return self._data.get(what)

    def respond(self, key: str, params: str) -> list[tuple[str, bytes]]:
        """Answer a query on ``curio/<rover>/q/<what>`` (any matching ``what``)."""
        data = self._data
        return [(rover_key(self.rover, f"q/{what}"), payload) for what, payload in data.items()
                if keyexpr_intersects(key, rover_key(self.rover, f"q/{what}"))]


class FleetBridge:
    """The rover's fleet part (see the module docstring).

    Args:
        cfg: the application config (``fleet`` and ``tours.min_battery_v``).
        rover: this rover's name.
        bus, clock: injected.
        transport: the network.
        robot: the robot model (home, laser pose).
        verifier, executor: signed commands in.
        traffic: the traffic part (None: off).
        goal_active: whether the navigator has a goal.
        snapshots_of: extra queryable snapshots, ``{name: callable returning JSON data}``
            (paths, tours), refreshed every status period.
    """

    def __init__(self, cfg: Config, rover: str, bus: Bus, clock: Clock, transport: Transport,
                 robot: RobotModel, verifier: CommandVerifier, executor: CommandExecutor,
                 traffic: TrafficNode | None, goal_active: Callable[[], bool],
                 snapshots_of: dict[str, Callable[[], Any]] | None = None) -> None:
        self.cfg = cfg
        self.fcfg = cfg.fleet
        self.rover = rover
        self.bus = bus
        self.clock = clock
        self.transport = transport
        self.robot = robot
        self.verifier = verifier
        self.executor = executor
        self.traffic = traffic
        self.goal_active = goal_active
        self.snapshots = QuerySnapshots(rover)
        self.snapshots_of = snapshots_of or {}
        self._peer_handlers: list[tuple[str, PeerHandler]] = []
        # More fields of the status message, each a callable returning a dict (zones).
        self.status_extras: list[Callable[[], dict[str, Any]]] = []
        # Where operators reach this rover's dashboard ('' = no link): fleet.dashboard_url, or
        # what the App finds out once its dashboard listens (curio/fleet/wiring.py).
        self.dashboard_url = cfg.fleet.dashboard_url
        self._event_seq = itertools.count(1)
        self._recent: deque[dict[str, Any]] = deque(maxlen=RECALL_EVENTS)
        self._ticks = 0
        self._last: dict[str, Any] = {}
        self._health: dict[str, str] = {}
        self.link_up: bool | None = None
        self.manager_seen = False
        self.refused = 0
        self.accepted = 0
        self.opened = asyncio.Event()

    # --- declarations -----------------------------------------------------------------------
    def on_peer(self, topic: str, handler: PeerHandler) -> None:
        """Call ``handler(rover, message)`` for JSON samples other rovers publish on
        ``curio/<rover>/<topic>`` (declare before the part starts)."""
        self._peer_handlers.append((topic, handler))

    def declare(self) -> None:
        """Subscriptions, queryables and the token (made on the network when it opens)."""
        t = self.transport
        t.subscribe(rover_key(self.rover, "cmd"), self._on_command)
        for topic, handler in self._peer_handlers:
            t.subscribe(f"curio/*/{topic}", self._peer_sample(handler))
        t.watch_liveliness(MANAGER_TOKEN, self._on_manager)
        t.queryable(rover_key(self.rover, "q/*"), self.snapshots.respond)
        t.declare_token(rover_key(self.rover, "alive"))

    def _peer_sample(self, handler: PeerHandler) -> Callable[[Sample], None]:
        def on_sample(sample: Sample) -> None:
            name = rover_of(sample.key)
            if name is None or name == self.rover:
                return
            try:
                handler(name, codec.loads(sample.payload))
            except codec.DecodeError:
                log.debug("fleet: a malformed sample on %s was dropped", sample.key)
        return on_sample

    def _on_manager(self, sample: Sample) -> None:
        seen = sample.kind == "put"
        if seen != self.manager_seen:
            self.manager_seen = seen
            self._event("fleet.manager_seen" if seen else "fleet.manager_lost")

    # --- commands ---------------------------------------------------------------------------
    def _on_command(self, sample: Sample) -> None:
        try:
            verified = self.verifier.verify(sample.payload)
        except CommandRefused as exc:
            self.refused += 1
            self._reply(None, Outcome(False, str(exc)))
            self._event("fleet.command_refused", reason=str(exc))
            return
        outcome = self.executor.execute(verified)
        if outcome.ok:
            self.accepted += 1
            self._event("fleet.command", action=verified.cmd.get("action"), key=verified.key,
                        request_id=outcome.request_id, duplicate=outcome.duplicate)
        else:
            self.refused += 1
            self._event("fleet.command_refused", action=verified.cmd.get("action"),
                        key=verified.key, reason=outcome.reason)
        self._reply(verified.cmd, outcome)

    def _reply(self, cmd: dict[str, Any] | None, outcome: Outcome) -> None:
        body = {"t": self.clock.wall_time(), "ok": outcome.ok, "reason": outcome.reason,
                "request_id": outcome.request_id or (cmd or {}).get("request_id", ""),
                "action": (cmd or {}).get("action")}
        self.transport.put(rover_key(self.rover, "reply"), codec.dumps(body))

    def _event(self, kind: str, **detail: Any) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, detail))

    # --- the parts --------------------------------------------------------------------------
    async def run(self) -> None:
        """Open the link (off the loop, retried), then publish until cancelled."""
        opener = asyncio.create_task(self._open(), name="fleet.open")
        try:
            await self._publish_loop()
        finally:
            opener.cancel()

    async def _open(self) -> None:
        while True:
            try:
                await self.clock.offload(self.transport.open)
                self.opened.set()
                return
            except FleetSetupError as exc:
                log.error("%s; retrying in %.0f s", exc, OPEN_RETRY_S)
                self._health["fleet.open"] = str(exc)
            await self.clock.sleep(OPEN_RETRY_S)

    async def run_pump(self) -> None:
        """Hand received samples to their handlers on the loop, every ``pump_period_s``."""
        async for _ in self.clock.every(self.fcfg.pump_period_s, phase_s=0.011):
            self.transport.pump()

    async def close(self) -> None:
        """Close the link."""
        self.transport.close()

    async def _publish_loop(self) -> None:
        f = self.fcfg
        period = 1.0 / f.pose_rate_hz
        events = self.bus.subscribe(EVENTS)
        health = self.bus.subscribe(HEALTH, maxsize=256)
        due = {"status": 0.0, "scan": 0.0, "health": 0.0}
        try:
            async for now in self.clock.every(period, phase_s=0.017):
                self._fast(events)
                for h in health.drain():
                    self._health[h.name] = h.state
                if now >= due["status"]:
                    due["status"] = now + f.status_period_s
                    self._slow()
                if f.scan_rate_hz > 0 and now >= due["scan"]:
                    due["scan"] = now + 1.0 / f.scan_rate_hz
                    self._scan()
                if now >= due["health"]:
                    due["health"] = now + f.health_period_s
                    self._put("health", {"t": self.clock.wall_time(), "parts": self._health})
        finally:
            events.close()
            health.close()

    def _put(self, topic: str, body: dict[str, Any]) -> None:
        self.transport.put(rover_key(self.rover, topic), codec.dumps(body))

    def _fast(self, events: Any) -> None:
        """Every tick: pose, traffic, events, and what changed (plan, tour, battery)."""
        wall = self.clock.wall_time()
        pose = self.bus.latest(POSE)
        odom = self.bus.latest(ODOM)
        if pose is not None:
            self._put("pose", {"t": wall, "x": pose.pose.x, "y": pose.pose.y,
                               "yaw": pose.pose.yaw,
                               "v": odom.linear_mps if odom is not None else 0.0,
                               "w": odom.angular_radps if odom is not None else 0.0})
        self._ticks += 1
        if self.traffic is not None and (self.goal_active() or self._ticks % IDLE_EVERY == 0):
            self._put("traffic", self.traffic.message())
        if self.fcfg.share_sim_truth:
            truth = self.bus.latest(GROUND_TRUTH)
            if truth is not None:
                self._put("sim/truth", {"t": wall, "x": truth.pose.x, "y": truth.pose.y,
                                        "yaw": truth.pose.yaw})
        now = self.clock.now()
        for ev in events.drain():
            body = {"t": wall - (now - ev.stamp), "seq": next(self._event_seq),
                    "kind": ev.kind, "detail": to_jsonable(ev.detail, 4)}
            self._put("events", body)
            if ev.kind.startswith(RECALLED):
                self._recent.append(body)
                self.snapshots.set("events", codec.dumps({"t": wall,
                                                          "events": list(self._recent)}))
        self._changed("plan", PLAN, self._plan_body)
        self._changed("tour", TOUR, lambda m: {"t": wall, **to_jsonable(m, 3)})
        self._changed("battery", BATTERY, lambda m: {"t": wall, "v": m.voltage_v,
                                                     "low": m.low})
        grid = self.bus.latest(MAP)
        if grid is not None and grid is not self._last.get("map"):
            self._last["map"] = grid
            self.snapshots.set("map", codec.encode_map(grid))
            self._last["map_sha"] = codec.grid_digest(grid.data)

    def _changed(self, topic: str, source: Any, body: Callable[[Any], dict[str, Any]]) -> None:
        msg = self.bus.latest(source)
        if msg is not None and msg is not self._last.get(topic):
            self._last[topic] = msg
            self._put(topic, body(msg))

    def _plan_body(self, plan: Any) -> dict[str, Any]:
        pts = codec.thin_path([(p.x, p.y) for p in plan.poses], self.fcfg.plan_step_m)
        body = {"t": self.clock.wall_time(), "pts": [[x, y] for x, y in pts]}
        self.snapshots.set("plan", codec.dumps(body))
        return body

    def _slow(self) -> None:
        """Every status period: the status, the link check, the snapshots, own health."""
        self._put("status", self.status())
        self._check_link()
        for name, fn in self.snapshots_of.items():
            try:
                self.snapshots.set(name, codec.dumps({"t": self.clock.wall_time(),
                                                      name: to_jsonable(fn(), 4)}))
            except Exception:
                log.exception("fleet: the %s snapshot failed", name)
        stats = self.transport.stats.totals()
        state = "ok" if self.link_up else "degraded"
        self.bus.publish(HEALTH, DriverHealth(
            self.clock.now(), "fleet", state,
            "" if self.link_up else "no link to the fleet: the rover carries on by itself",
            counters={"out_msgs": float(stats["out_msgs"]), "out_bytes": float(stats["out_bytes"]),
                      "in_msgs": float(stats["in_msgs"]),
                      "dropped": float(self.transport.stats.dropped),
                      "commands": float(self.accepted), "refused": float(self.refused)}))

    def _check_link(self) -> None:
        up = self.transport.connected
        if up != self.link_up:
            if self.link_up is not None or not up:
                self._event("fleet.link_restored" if up else "fleet.link_lost")
            self.link_up = up

    def status(self) -> dict[str, Any]:
        """The status message (see the module docstring)."""
        status = self.bus.latest(STATUS)
        estop = self.bus.latest(ESTOP)
        loc = self.bus.latest(LOCALIZATION)
        tour = self.bus.latest(TOUR)
        battery = self.bus.latest(BATTERY)
        pose = self.bus.latest(POSE)
        ready = readiness(self.bus, self.cfg.tours.min_battery_v, self.cfg.localization.enabled)
        d = self.traffic.decision if self.traffic is not None else None
        home = self.robot.home
        return {
            "t": self.clock.wall_time(), "rover": self.rover,
            "state": status.state if status else "starting", "text": status.text if status else "",
            "estop": bool(estop.engaged) if estop else False,
            "estop_by": estop.source if estop and estop.engaged else "",
            "loc": loc.state if loc else "unknown", "goal": self.goal_active(),
            "tour": tour.tour_id if tour else None, "tour_name": tour.name if tour else "",
            "tour_phase": tour.phase if tour else "idle",
            "stop": tour.stop_index if tour else None, "stops": tour.stops_total if tour else 0,
            "battery_v": battery.voltage_v if battery else None,
            "battery_low": battery.low if battery else False,
            "x": pose.pose.x if pose else None, "y": pose.pose.y if pose else None,
            "yaw": pose.pose.yaw if pose else None, "home": [home.x, home.y, home.yaw],
            "ready": ready.ready, "why": ready.reason,
            "map": self._last.get("map_sha", ""), "link": bool(self.link_up),
            "traffic": d.state if d else "off", "yield_to": d.yield_to if d else None,
            "dashboard": self.dashboard_url, **self._power_status(),
            **{k: v for extra in self.status_extras for k, v in extra().items()},
        }

    def _power_status(self) -> dict[str, Any]:
        """The power model (``/power``) and the dock (``/dock``) for the status message:
        ``soc`` 0..1, ``power_level``, ``charging``, ``time_left_s``, ``time_to_full_s``
        (None until ``/power`` has spoken) and ``dock`` (None: no dock fitted)."""
        power = self.bus.latest(POWER)
        dock = self.bus.latest(DOCK)
        out: dict[str, Any] = {
            "soc": round(power.soc, 3) if power else None,
            "power_level": power.level if power else None,
            "charging": bool(power.charging) if power else False,
            "time_left_s": _rounded(power.time_left_s) if power else None,
            "time_to_full_s": _rounded(power.time_to_full_s) if power else None,
            "dock": None}
        if self.cfg.dock.enabled:
            out["dock"] = {"state": dock.state if dock else "idle",
                           "charging": bool(dock.charging) if dock else False,
                           "attempt": dock.attempt if dock else 0,
                           "detail": dock.detail if dock else ""}
        return out

    def _scan(self) -> None:
        scan = self.bus.latest(SCAN)
        pose = self.bus.latest(POSE)
        if scan is None or pose is None or scan is self._last.get("scan"):
            return
        self._last["scan"] = scan
        laser = pose.pose @ self.robot.laser_in_base
        payload = codec.encode_scan(scan, laser, self.clock.wall_time(), self.fcfg.scan_beams)
        self.transport.put(rover_key(self.rover, "scan"), payload)


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 1)
