"""The safety stage: the only publisher of ``/cmd_vel`` (DESIGN rule 6).

Every velocity source passes through it: the local controller, recovery and scenarios on
``/cmd_vel_nav``, the dashboard's teleop on ``/cmd_vel_teleop`` (which takes precedence while it
is fresh). At ``rate_hz`` it publishes one :class:`~curio.core.messages.Twist` in ``base_link``
(forward m/s, yaw rate rad/s) after, in order:

1. **Latched e-stop** — an operator ``estop`` command stops the rover at once and keeps it
   stopped until ``release_estop``; the state is published on ``/estop``.
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

import math
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus, Subscription
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
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
from curio.safety.kernel import polygon_distances_into, sweep_stop_zone

if TYPE_CHECKING:
    from curio.app import App

__all__ = [
    "CURIO_WHEEL_POSITIONS_M",
    "SafetyStage",
    "StopZone",
    "approach",
    "fastest_wheel_speed_mps",
    "limit_to_wheel_speed",
    "polygon_distances",
    "register_safety",
]

F64 = npt.NDArray[np.float64]

# Wheel contact points in base_link (x, y), metres: FL, ML, BL, FR, MR, BR (hardware.md §2.1).
CURIO_WHEEL_POSITIONS_M: tuple[tuple[float, float], ...] = (
    (0.280, 0.235), (0.0, 0.260), (-0.250, 0.235),
    (0.280, -0.235), (0.0, -0.260), (-0.250, -0.235),
)


def fastest_wheel_speed_mps(
    linear_mps: float,
    angular_radps: float,
    wheels: tuple[tuple[float, float], ...] = CURIO_WHEEL_POSITIONS_M,
) -> float:
    """Speed of Curio's fastest wheel for a body twist, m/s.

    Wheel ``i`` at ``(x, y)`` moves at ``|ω| · hypot(x, r − y)`` with ``r = v / ω``, i.e.
    ``hypot(x·ω, v − y·ω)`` (hardware.md §2.2); for ``ω = 0`` every wheel moves at ``|v|``.
    """
    return max(math.hypot(x * angular_radps, linear_mps - y * angular_radps) for x, y in wheels)


def limit_to_wheel_speed(
    linear_mps: float,
    angular_radps: float,
    max_wheel_speed_mps: float,
    wheels: tuple[tuple[float, float], ...] = CURIO_WHEEL_POSITIONS_M,
) -> tuple[float, float]:
    """Scale ``(v, ω)`` together so no wheel exceeds ``max_wheel_speed_mps`` (keeps the radius)."""
    fastest = fastest_wheel_speed_mps(linear_mps, angular_radps, wheels)
    if fastest <= max_wheel_speed_mps or fastest <= 0.0:
        return linear_mps, angular_radps
    k = max_wheel_speed_mps / fastest
    return linear_mps * k, angular_radps * k


def polygon_distances(points: F64, polygon: F64) -> F64:
    """Signed distance from each point to a polygon's boundary, metres (negative inside).

    Args:
        points: ``(..., 2)`` points in the polygon's frame.
        polygon: ``(E, 2)`` vertices, either orientation.
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = np.ascontiguousarray(pts.reshape(-1, 2))
    out = np.empty(flat.shape[0])
    polygon_distances_into(flat, np.ascontiguousarray(polygon, dtype=np.float64), out)
    shaped: F64 = out.reshape(pts.shape[:-1])
    return shaped


def convex_hull(points: F64) -> F64:
    """Convex hull ``(M, 2)`` of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted({(float(x), float(y)) for x, y in points})
    if len(pts) < 3:
        return np.asarray(pts, dtype=np.float64)

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.asarray(lower[:-1] + upper[:-1], dtype=np.float64)


def arc_poses(linear_mps: float, angular_radps: float, times_s: F64) -> F64:
    """Poses ``(K, 3)`` (x, y, yaw) reached by a constant twist after each of ``times_s``."""
    th = angular_radps * times_s
    if abs(angular_radps) < 1e-6:
        x = linear_mps * times_s
        y = np.zeros_like(times_s)
    else:
        r = linear_mps / angular_radps
        x = r * np.sin(th)
        y = r * (1.0 - np.cos(th))
    return np.stack([x, y, th], axis=-1)


@dataclass
class StopZoneResult:
    """What the stop zone allows for one command.

    Attributes:
        factor: 0..1 multiplier for both ``v`` and ``ω`` (0 = stop).
        reason: ``""``, ``"slow"`` or ``"stop"``.
        clearance_m: smallest predicted distance between the footprint and an approached point.
        time_to_contact_s: when the margin would be reached at the commanded speed (inf: never).
    """

    factor: float
    reason: str = ""
    clearance_m: float = math.inf
    time_to_contact_s: float = math.inf


class StopZone:
    """Predicts contact of the swept footprint with scan points (all in ``base_link``).

    Args:
        footprint: polygon vertices in ``base_link``, metres.
        stop_distance_m: margin kept around the footprint.
        slow_distance_m: approached points nearer than this slow the rover.
        lookahead_s: how far ahead the commanded arc is swept.
        contact_margin_m: margin for points already inside ``stop_distance_m`` and for pure turns.
        slow_min_fraction: the slowest the slow zone makes the rover (fraction of the command).
        steps: samples along the sweep.
    """

    def __init__(
        self,
        footprint: list[tuple[float, float]],
        stop_distance_m: float,
        slow_distance_m: float,
        lookahead_s: float,
        contact_margin_m: float = 0.02,
        slow_min_fraction: float = 0.4,
        steps: int = 10,
    ) -> None:
        self.footprint = np.asarray(footprint, dtype=np.float64)
        self.stop_distance_m = stop_distance_m
        self.slow_distance_m = max(slow_distance_m, stop_distance_m)
        self.lookahead_s = lookahead_s
        self.contact_margin_m = min(contact_margin_m, stop_distance_m)
        self.slow_min_fraction = slow_min_fraction
        self.steps = steps
        self.radius_m = float(np.max(np.hypot(self.footprint[:, 0], self.footprint[:, 1])))
        self.points: F64 = np.zeros((0, 2))
        self._poly_cache: dict[float, F64] = {}

    def _extended(self, dx_m: float) -> F64:
        """The footprint swept ``dx_m`` along x (its convex hull), the stop or slow polygon."""
        key = round(dx_m, 6)
        poly = self._poly_cache.get(key)
        if poly is None:
            shifted = self.footprint + np.array([dx_m, 0.0])
            poly = convex_hull(np.vstack([self.footprint, shifted]))
            self._poly_cache[key] = poly
        return poly

    def set_points(self, points_base: F64) -> None:
        """Replace the obstacle points ``(N, 2)`` in ``base_link``."""
        self.points = np.asarray(points_base, dtype=np.float64).reshape(-1, 2)

    def evaluate(self, linear_mps: float, angular_radps: float) -> StopZoneResult:
        """How much of the command ``(v, ω)`` the obstacles allow."""
        if self.points.size == 0 or (abs(linear_mps) < 1e-6 and abs(angular_radps) < 1e-6):
            return StopZoneResult(1.0)
        reach = (self.radius_m + self.slow_distance_m + abs(linear_mps) * self.lookahead_s
                 + 0.05)
        dt = self.lookahead_s / self.steps
        times = np.arange(self.steps + 1, dtype=np.float64) * dt
        poses = arc_poses(linear_mps, angular_radps, times)  # (K, 3)
        pure_turn = abs(linear_mps) < 1e-3
        direction = 0.0 if pure_turn else math.copysign(1.0, linear_mps)
        stop_poly = self._extended(direction * self.stop_distance_m)
        use_slow = self.slow_distance_m > self.stop_distance_m and not pure_turn
        slow_poly = self._extended(direction * self.slow_distance_m) if use_slow else stop_poly
        # Compiled sweep (safety_kernel): per point within reach and outside the footprint,
        # its distances to the stop polygon along the arc, reduced to what is decided below.
        approached, clearance, first_hit, slow_near = sweep_stop_zone(
            self.points, reach, poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]),
            self.footprint, stop_poly, slow_poly, use_slow, self.contact_margin_m)
        if not approached:
            return StopZoneResult(1.0)
        factor = 1.0
        reason = ""
        ttc = math.inf
        if first_hit >= 0:  # first step (0-based over times[1:]) reaching the contact margin
            ttc = float(times[first_hit + 1])
            factor = min(1.0, float(times[first_hit]) / self.lookahead_s)
            reason = "stop" if factor <= 0.0 else "slow"
        if slow_near < math.inf:  # an approached point inside the slow polygon
            near = max(0.0, float(slow_near))
            span = self.slow_distance_m - self.stop_distance_m
            slow = min(1.0, max(self.slow_min_fraction, near / span))
            if slow < factor:
                factor = slow
                reason = reason or "slow"
        return StopZoneResult(factor, reason, float(clearance), ttc)


def approach(current: float, target: float, max_step: float) -> float:
    """Move ``current`` towards ``target`` by at most ``max_step`` (a per-cycle rate limit)."""
    if target > current + max_step:
        return current + max_step
    if target < current - max_step:
        return current - max_step
    return target


class SafetyStage:
    """Turns the wanted velocities into the one the base executes (see the module docstring).

    Args:
        cfg: the application config (``nav.safety``, ``robot``).
        clock: the injected clock.
        bus: the application bus.
    """

    def __init__(self, cfg: Config, clock: Clock, bus: Bus) -> None:
        self.cfg = cfg
        self.scfg = cfg.nav.safety
        self.clock = clock
        self.bus = bus
        s = self.scfg
        self.zone = StopZone(
            [(float(p[0]), float(p[1])) for p in cfg.robot.footprint], s.stop_distance_m,
            s.slow_distance_m, s.lookahead_s, s.contact_margin_m, s.slow_min_fraction,
        )
        lx, ly, lyaw = cfg.robot.laser_pose
        self.laser_in_base = Pose2D(lx, ly, lyaw)
        self.max_wheel_speed_mps = cfg.robot.max_wheel_speed_mps
        self.estop_engaged = False
        self.estop_reason = ""
        self._nav: Twist | None = None
        self._teleop: Twist | None = None
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

    # --- inputs ---------------------------------------------------------------------------
    def on_nav(self, msg: Twist) -> None:
        """A command from the controller, recovery or a scenario."""
        self._nav = msg

    def on_teleop(self, msg: Twist) -> None:
        """A command from the operator's teleop."""
        self._teleop = msg

    def on_scan(self, scan: LaserScan) -> None:
        """The latest lidar revolution: its valid points become the stop zone's obstacles."""
        mask = scan.valid_mask()
        r = scan.ranges_m[mask].astype(np.float64)
        a = scan.angles_rad[mask]
        pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
        self.zone.set_points(self.laser_in_base.transform_points(pts))
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
        self.bus.publish(ESTOP, EStop(now, False, source=source, reason="released"))
        if was:
            self.bus.publish(EVENTS, Event(now, "safety.estop",
                                           {"engaged": False, "source": source}))

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
        w = max(-s.max_angular_radps, min(s.max_angular_radps, w))
        lv, lw = limit_to_wheel_speed(v, w, self.max_wheel_speed_mps)
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
        # Stop zone.
        zone = self.zone.evaluate(v, w) if (v or w) else StopZoneResult(1.0)
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
               wodom: Subscription[Odometry], op: Subscription[OperatorCommand]) -> None:
        for cmd in op.drain():
            self.on_operator(cmd)
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
        try:
            async for now in self._every(period):
                self._drain(nav, teleop, scan, odom, wodom, op)
                self.step()
                if now - last_health >= 1.0:
                    last_health = now
                    bus.publish(HEALTH, self.health())
        finally:
            for sub in (nav, teleop, scan, odom, wodom, op):
                sub.close()
            self.bus.publish(CMD_VEL, Twist(self.clock.now(), 0.0, 0.0, source="safety:stop"))

    def _every(self, period: float) -> AsyncIterator[float]:
        every = getattr(self.clock, "every", None)
        if every is not None:
            it: AsyncIterator[float] = every(period)
            return it
        return self._fallback_every(period)

    async def _fallback_every(self, period: float) -> AsyncIterator[float]:
        while True:
            await self.clock.sleep(period)
            yield self.clock.now()


def register_safety(app: App) -> SafetyStage:
    """Build the safety stage, set ``app.safety`` and register its part and halt hook."""
    from curio.app import Part

    stage = SafetyStage(app.cfg, app.clock, app.bus)
    app.safety = stage

    async def halt() -> None:
        app.bus.publish(CMD_VEL, Twist(app.clock.now(), 0.0, 0.0, source="safety:halt"))

    app.add(Part("safety", run=stage.run))
    app.add_halt_hook(halt)
    return stage
