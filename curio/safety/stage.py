"""The safety stage: the only publisher of ``/cmd_vel`` (DESIGN rule 6).

Every velocity source passes through it: the local controller, recovery and scenarios on
``/cmd_vel_nav``, the dashboard's teleop on ``/cmd_vel_teleop`` (which takes precedence while it
is fresh). At ``rate_hz`` it publishes one :class:`~curio.core.messages.Twist` in ``base_link``
(forward m/s, yaw rate rad/s) after, in order:

1. **Latched e-stop** — an operator ``estop`` command stops the rover at once and keeps it
   stopped until ``release_estop``; the state is published on ``/estop``. Operator commands
   are handled the moment they arrive (their own task, not the next control cycle): the e-stop
   publishes a zero ``/cmd_vel`` in the same event-loop turn, and no flood of other commands
   or velocities can delay it. ``EStop.source`` names who set or released it (``web:<name>``).
2. **Command watchdog** — a source silent for longer than ``cmd_timeout_s`` (teleop:
   ``teleop_timeout_s``) counts as zero; the output ramps down to zero.
3. **Limits** — ``|v| ≤ max_speed_mps``, ``|ω| ≤ max_angular_radps``, and Curio's fastest
   *wheel* ≤ ``robot.max_wheel_speed_mps`` (0.37 m/s; both components are scaled together so
   the turning radius is kept, as the base controller does, hardware.md §2.2).
4. **Stop zone** — the footprint (``robot.footprint``) is swept along the commanded arc for
   ``lookahead_s`` against the latest scan (points in ``base_link``). Only points the motion
   *approaches* count, so backing away from, or turning away from, an obstacle is never
   blocked. The speed is scaled so that the rover would reach the ``stop_distance_m`` margin
   only after ``lookahead_s``, and to at most ``slow_min_fraction`` … 1 inside
   ``slow_distance_m``. Points already inside the margin (a tight doorway) and pure turns only
   have to stay ``contact_margin_m`` clear.
5. **Acceleration smoothing** — ``max_accel_mps2`` / ``max_angular_accel_radps2``; a stop
   (stop zone, e-stop) brakes at up to ``max_brake_mps2``.

It publishes ``/health`` (name ``safety``) once a second and an :class:`~curio.core.messages.Event`
when it intervenes: ``safety.stop_zone`` (and ``safety.stop_zone_cleared``), ``safety.estop``,
``safety.watchdog``, ``safety.no_scan``.
"""

from __future__ import annotations

import asyncio
import math
from typing import Any

from curio.core.bus import Bus, Subscription
from curio.core.clock import Clock
from curio.core.config import SafetyConfig
from curio.core.geometry import approach
from curio.core.messages import (
    DriverHealth,
    EStop,
    Event,
    LaserScan,
    Odometry,
    OperatorCommand,
    Twist,
)
from curio.core.topics import (
    CMD_VEL,
    CMD_VEL_NAV,
    CMD_VEL_TELEOP,
    ESTOP,
    EVENTS,
    HEALTH,
    ODOM,
    OPERATOR,
    SCAN,
    WHEEL_ODOM,
)
from curio.robot import RobotModel
from curio.safety.stop_zone import StopZone, StopZoneResult

__all__ = ["DOCK_MARGIN_M", "SafetyStage"]

DOCK_MARGIN_M = 0.005  # what the stop zone keeps to the dock while docking

class SafetyStage:
    """Turns the wanted velocities into the one the base executes (see the module docstring).

    Args:
        cfg: ``nav.safety``.
        robot: the robot model (footprint, laser pose, wheel positions and limits).
        clock: the injected clock.
        bus: the application bus.
    """

    def __init__(self, cfg: SafetyConfig, robot: RobotModel, clock: Clock, bus: Bus) -> None:
        self.scfg = cfg
        self.robot = robot
        self.clock = clock
        self.bus = bus
        s = cfg
        self.zone = StopZone(
            robot.footprint_points, s.stop_distance_m, s.slow_distance_m, s.lookahead_s,
            s.contact_margin_m, s.slow_min_fraction,
        )
        self.max_angular_radps = min(s.max_angular_radps, robot.max_angular_radps)
        self.estop_engaged = False
        self.estop_reason = ""
        self._nav: Twist | None = None
        self._teleop: Twist | None = None
        self._released_s = -math.inf
        self._scan_stamp: float | None = None
        self._started_s = clock.now()
        self._out_v = 0.0
        self._out_w = 0.0
        self._last_step_s: float | None = None
        self._zone_state = ""
        self._watchdog_tripped = False
        self._no_scan = False
        self.measured: Odometry | None = None
        self.last_output = Twist(clock.now(), 0.0, 0.0, source="safety")
        self.last_source = ""
        self.last_zone = StopZoneResult(1.0)
        self.counters: dict[str, float] = {
            "cycles": 0, "stop_zone_stops": 0, "slowed_cycles": 0, "estops": 0,
            "watchdog_trips": 0, "wheel_limited_cycles": 0,
        }
        # Zones drawn on the map (curio/zones/guard.py): limit(v, w) -> (v, w) or None.
        self.zone_guard: Any = None
        # Docking (curio/docking): until this clock time the stop zone only prevents contact
        # and the speed is capped, so the rover can close on its dock.
        self._docking_until = -math.inf
        self._docking_speed_mps = 0.0
        self.dock_zone = StopZone(robot.footprint_points, DOCK_MARGIN_M, DOCK_MARGIN_M,
                                  0.5, DOCK_MARGIN_M, 1.0)

    # --- inputs ---------------------------------------------------------------------------
    def on_nav(self, msg: Twist) -> None:
        """A command from the controller, recovery or a scenario (ignored if older than the
        last e-stop release)."""
        if msg.stamp >= self._released_s:
            self._nav = msg

    def on_teleop(self, msg: Twist) -> None:
        """A command from the operator's teleop (ignored if older than the last release)."""
        if msg.stamp >= self._released_s:
            self._teleop = msg

    def on_scan(self, scan: LaserScan) -> None:
        """The latest lidar revolution: its valid points become the stop zone's obstacles."""
        self.zone.set_points(scan.points(self.robot.laser_in_base))
        self._scan_stamp = scan.stamp

    def on_odom(self, msg: Odometry) -> None:
        """The measured velocity (for health and reports)."""
        self.measured = msg

    def on_operator(self, cmd: OperatorCommand) -> None:
        """Handle ``estop`` / ``release_estop``; other actions are not the safety stage's."""
        if cmd.action == "estop":
            self.engage_estop(cmd.source or "operator", "operator pressed e-stop")
        elif cmd.action == "release_estop":
            self.release_estop(cmd.source or "operator")

    def engage_estop(self, source: str, reason: str) -> None:
        """Latch the e-stop: the output is zero until :meth:`release_estop`."""
        now = self.clock.now()
        if not self.estop_engaged:
            self.counters["estops"] += 1
        self.estop_engaged = True
        self.estop_reason = reason
        self._out_v = 0.0
        self._out_w = 0.0
        self._nav = None
        self._teleop = None
        self.bus.publish(ESTOP, EStop(now, True, source=source, reason=reason))
        self.bus.publish(EVENTS, Event(now, "safety.estop",
                                       {"engaged": True, "source": source, "reason": reason}))
        self.bus.publish(CMD_VEL, Twist(now, 0.0, 0.0, source="safety:estop"))

    def release_estop(self, source: str) -> None:
        """Release the latched e-stop (commands older than the release are ignored)."""
        now = self.clock.now()
        was = self.estop_engaged
        self.estop_engaged = False
        self.estop_reason = ""
        self._nav = None
        self._teleop = None
        self._released_s = now
        self.bus.publish(ESTOP, EStop(now, False, source=source, reason="released"))
        if was:
            self.bus.publish(EVENTS, Event(now, "safety.estop",
                                           {"engaged": False, "source": source}))

    def allow_docking(self, until_s: float, max_speed_mps: float) -> None:
        """Let the rover close on its dock until clock time ``until_s``: the stop zone then
        keeps only ``DOCK_MARGIN_M`` to what is ahead and the speed is capped at
        ``max_speed_mps`` (the docking behaviour renews it every cycle of its approach), for
        the commands on ``/cmd_vel_nav`` only: teleop keeps the whole stop zone."""
        self._docking_until = until_s
        self._docking_speed_mps = max_speed_mps

    # --- the control step -------------------------------------------------------------------
    def _event(self, kind: str, **detail: object) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, dict(detail)))

    def _select(self, now: float) -> tuple[float, float, str]:
        s = self.scfg
        if self._teleop is not None and now - self._teleop.stamp <= s.teleop_timeout_s:
            return self._teleop.linear_mps, self._teleop.angular_radps, "teleop"
        if self._nav is not None and now - self._nav.stamp <= s.cmd_timeout_s:
            return self._nav.linear_mps, self._nav.angular_radps, "nav"
        return 0.0, 0.0, ""

    def _zones_and_docking(self, v: float, w: float, now: float,
                           source: str) -> tuple[float, float, StopZone, bool]:
        """Zones drawn on the map (keep-out ahead, speed limits), then the docking allowance:
        the command, the stop zone to use and whether the command was reduced. The allowance
        is for the docker's own commands (``nav``): an operator's teleop meanwhile meets the
        whole stop zone (a hand on the joystick 1 cm before the dock drove the rover into it
        under the 5 mm margin: the 24-hour soak of 2026-12-07, seed 2)."""
        v0, w0 = v, w
        if self.zone_guard is not None and (v or w):
            v, w = self.zone_guard.limit(v, w)
        stop_zone = self.zone
        if now < self._docking_until and source == "nav":
            stop_zone = self.dock_zone
            cap = self._docking_speed_mps
            if abs(v) > cap:
                w *= cap / abs(v)
                v = math.copysign(cap, v)
        limited = abs(v) < abs(v0) - 1e-9 or abs(w) < abs(w0) - 1e-9
        return v, w, stop_zone, limited

    def would_allow(self, linear_mps: float, angular_radps: float) -> bool:
        """Whether the stop zone, on the latest scan, would let the command ``(v m/s, ω
        rad/s)`` move the rover now (not only stop it): for a planner choosing among
        manoeuvres. It decides nothing: every command still passes :meth:`step`."""
        return self.zone.evaluate(linear_mps, angular_radps).factor > 0.0

    def step(self) -> Twist:
        """Compute, publish and return the next ``/cmd_vel`` (call at ``rate_hz``)."""
        s = self.scfg
        now = self.clock.now()
        dt = 1.0 / s.rate_hz if self._last_step_s is None else max(0.0, now - self._last_step_s)
        dt = min(dt, 2.0 / s.rate_hz)
        self._last_step_s = now
        self.counters["cycles"] += 1
        if self.estop_engaged:
            self._out_v = self._out_w = 0.0
            out = Twist(now, 0.0, 0.0, source="safety:estop")
            self.last_output = out
            self.bus.publish(CMD_VEL, out)
            return out
        v, w, source = self._select(now)
        had_input = (self._teleop is not None or self._nav is not None)
        if not source and had_input and not self._watchdog_tripped and (
                abs(self._out_v) > 1e-6 or abs(self._out_w) > 1e-6):
            self._watchdog_tripped = True
            self.counters["watchdog_trips"] += 1
            self._event("safety.watchdog", detail="velocity command stale: ramping to zero")
        if source:
            self._watchdog_tripped = False
        self.last_source = source
        # Limits.
        v = max(-s.max_speed_mps, min(s.max_speed_mps, v))
        w = max(-self.max_angular_radps, min(self.max_angular_radps, w))
        lv, lw = self.robot.limit_to_wheel_speed(v, w)
        if (lv, lw) != (v, w):
            self.counters["wheel_limited_cycles"] += 1
        v, w = lv, lw
        # No scan: stop (the stop zone would be blind).
        scan_age = now - (self._scan_stamp if self._scan_stamp is not None else self._started_s)
        blind = s.require_scan and scan_age > s.scan_timeout_s
        if blind != self._no_scan:
            self._no_scan = blind
            self._event("safety.no_scan", blind=blind, scan_age_s=round(scan_age, 3))
        braking = False
        if blind:
            v = w = 0.0
            braking = True
        v, w, stop_zone, limited = self._zones_and_docking(v, w, now, source)
        braking = braking or limited
        # Stop zone.
        zone = stop_zone.evaluate(v, w) if (v or w) else StopZoneResult(1.0)
        self.last_zone = zone
        if zone.factor < 1.0:
            self.counters["slowed_cycles"] += 1
            v *= zone.factor
            w *= zone.factor
            braking = True
        state = "stop" if zone.reason == "stop" else ""
        if state != self._zone_state:
            if state == "stop":
                self.counters["stop_zone_stops"] += 1
                self._event("safety.stop_zone", clearance_m=round(zone.clearance_m, 3),
                            source=source)
            else:
                self._event("safety.stop_zone_cleared")
            self._zone_state = state
        # Acceleration smoothing (braking towards zero may use the harder limit).
        acc_v = s.max_accel_mps2
        acc_w = s.max_angular_accel_radps2
        if braking:
            boost = max(1.0, s.max_brake_mps2 / s.max_accel_mps2)
            acc_v *= boost
            acc_w *= boost
        self._out_v = approach(self._out_v, v, acc_v * dt)
        self._out_w = approach(self._out_w, w, acc_w * dt)
        if abs(self._out_v) < 1e-9:
            self._out_v = 0.0
        if abs(self._out_w) < 1e-9:
            self._out_w = 0.0
        out = Twist(now, self._out_v, self._out_w, source=f"safety:{source or 'idle'}")
        self.last_output = out
        self.bus.publish(CMD_VEL, out)
        return out

    def health(self) -> DriverHealth:
        """The stage's health: ``error`` while e-stopped or blind, ``degraded`` when limiting."""
        now = self.clock.now()
        if self.estop_engaged:
            state, msg = "error", f"e-stop engaged ({self.estop_reason}); release it to drive"
        elif self._no_scan:
            state, msg = "error", "no lidar scan: the rover is held still; check the lidar"
        elif self._zone_state == "stop":
            state, msg = "degraded", "stop zone: an obstacle is in the way"
        else:
            state, msg = "ok", ""
        counters = dict(self.counters)
        if self.measured is not None:
            counters["measured_linear_mps"] = self.measured.linear_mps
            counters["measured_angular_radps"] = self.measured.angular_radps
        counters["out_linear_mps"] = self._out_v
        counters["out_angular_radps"] = self._out_w
        return DriverHealth(now, "safety", state, msg, counters)

    # --- task -------------------------------------------------------------------------------
    def _drain(self, nav: Subscription[Twist], teleop: Subscription[Twist],
               scan: Subscription[LaserScan], odom: Subscription[Odometry],
               wodom: Subscription[Odometry]) -> None:
        for t in nav.drain():
            self.on_nav(t)
        for t in teleop.drain():
            self.on_teleop(t)
        latest_scan = None
        for sc in scan.drain():
            latest_scan = sc
        if latest_scan is not None:
            self.on_scan(latest_scan)
        got_fused = False
        for o in odom.drain():
            self.on_odom(o)
            got_fused = True
        for o in wodom.drain():
            if not got_fused:
                self.on_odom(o)

    async def _watch_operator(self, op: Subscription[OperatorCommand]) -> None:
        """Handle each operator command as soon as it is published (e-stop without delay)."""
        async for cmd in op:
            self.on_operator(cmd)

    async def run(self) -> None:
        """Publish ``/cmd_vel`` at ``rate_hz`` until cancelled (then publish zero)."""
        bus = self.bus
        nav = bus.subscribe(CMD_VEL_NAV)
        teleop = bus.subscribe(CMD_VEL_TELEOP)
        scan = bus.subscribe(SCAN)
        odom = bus.subscribe(ODOM)
        wodom = bus.subscribe(WHEEL_ODOM)
        op = bus.subscribe(OPERATOR)
        bus.publish(ESTOP, EStop(self.clock.now(), False, source="safety", reason="start"))
        self._started_s = self.clock.now()
        period = 1.0 / self.scfg.rate_hz
        last_health = -math.inf
        operator = asyncio.ensure_future(self._watch_operator(op))
        try:
            async for now in self.clock.every(period):
                if operator.done():  # the e-stop path must never die silently
                    raise RuntimeError("the safety stage's operator watcher stopped") from (
                        None if operator.cancelled() else operator.exception())
                self._drain(nav, teleop, scan, odom, wodom)
                self.step()
                if now - last_health >= 1.0:
                    last_health = now
                    bus.publish(HEALTH, self.health())
        finally:
            operator.cancel()
            for sub in (nav, teleop, scan, odom, wodom, op):
                sub.close()
            self.bus.publish(CMD_VEL, Twist(self.clock.now(), 0.0, 0.0, source="safety:stop"))
