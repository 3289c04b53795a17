"""Docking as a behaviour: staging pose, final approach on the dock's shape, retries, undocking.

:class:`Docker` is a part (a 20 Hz loop on the injected clock) that the behaviour tree starts and
polls (behaviours never await). Docking:

1. ``staging`` — a navigator goal to the staging pose, ``dock.staging_distance_m`` straight out
   of the dock (through the waypoints of path 0 before home: the route home);
2. ``approaching`` — the navigator is idle; the lidar finds the dock's shape
   (:class:`~curio.docking.perception.DockDetector`: first around where the map puts it, then
   tracking the previous fix moved by odometry, so the approach is aligned on the dock itself,
   not on the map), and :class:`~curio.docking.approach.DockApproach` drives the final metres
   slowly on ``/cmd_vel_nav``; on its last, straight piece the safety stage is told the rover
   may close on the dock (``SafetyStage.allow_docking``: a 5 mm stop margin, the approach
   speed as the cap);
3. on the stop line it waits ``dock.contact_wait_s`` for the charger's voltage on the contacts
   (``/battery`` ``charger_v``); no voltage (a missed contact), or a fix off by more than the
   tolerance, and it **backs off** (``backing_off``) and tries again, up to
   ``dock.max_attempts``; then ``failed``. Without a contact measurement
   (``charger_v`` None) the lidar's fix alone decides;
   a fix, or the tracked estimate, that puts the dock farther from where the map and the
   localisation put it than ``dock.detect_range_m`` (or three standard deviations of ``/pose``)
   or :data:`MAP_GATE_RAD` is something else, or odometry that drifted: it is dropped, the
   next scans look around the map's dock again, and without a fix for ``LOST_SIGHT_S`` the
   attempt is retried (a seed-3 soak day of 2026-12-03 followed an estimate that turned 60°
   away from the dock, ended a metre off and could not back out);
4. ``docked``: stays there; charging shows on ``/power``.

Undocking (``undocking``) backs straight out ``dock.undock_distance_m``; the rover must undock
before it drives anywhere else (the tree does it before a tour or a path). A rover that starts
on the dock (at home within 5 cm and 0.1 rad) starts ``docked``; one that is moved off it
(teleop, a push) goes back to ``idle``.

Outputs: ``/dock`` (:class:`~curio.core.messages.DockState`) on every change, and events
``dock.started`` (reason), ``dock.staging_reached``, ``dock.attempt``, ``dock.retry`` (reason),
``dock.docked`` (attempts, error_m, error_deg, charging), ``dock.failed`` (reason),
``dock.undocked``, ``dock.left``.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from curio.core.bus import Bus, Subscription
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import DockState, Event, LaserScan, Odometry, Twist
from curio.core.pose_history import PoseHistory
from curio.core.topics import BATTERY, CMD_VEL_NAV, DOCK, EVENTS, ODOM, POSE, SCAN
from curio.robot import RobotModel

from .approach import ENTRY_X_M, DockApproach
from .home import HomeDock
from .perception import DockDetector, DockFix
from .station import DockShape

__all__ = ["BUSY_STATES", "Docker"]

log = logging.getLogger("curio.docking")

RATE_HZ = 20.0
BUSY_STATES = ("staging", "approaching", "backing_off", "waiting", "undocking")
LOST_SIGHT_S = 2.0
BACK_OFF_X_M = ENTRY_X_M - 0.15
ON_DOCK_M = 0.05
ON_DOCK_RAD = 0.1
FIX_GAIN = 0.3  # each new fix moves the tracked dock estimate this share of the way
MAP_GATE_RAD = math.radians(20.0)  # a dock estimate this far from the map's heading is not it


class Docker:
    """Docks and undocks the rover (see the module docstring).

    Args:
        cfg: the whole configuration (``[dock]``, ``[power]``).
        bus, clock: injected.
        robot: the footprint (the dock's shape follows it).
        navigator: sends the staging goal (``send_goal``, ``cancel``, ``active``).
        home: the home/dock pose.
        safety: has ``allow_docking(until_s, max_speed_mps)`` (None in tests).
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock, robot: RobotModel, navigator: Any,
                 home: HomeDock, safety: Any = None) -> None:
        self.cfg = cfg
        self.dcfg = cfg.dock
        self.bus = bus
        self.clock = clock
        self.navigator = navigator
        self.home = home
        self.safety = safety
        self.shape = DockShape.for_footprint(robot.footprint)
        self.detector = DockDetector(self.shape, self.dcfg.detect_range_m)
        self.approach = DockApproach(self.dcfg.approach_speed_mps,
                                     self.dcfg.min_approach_speed_mps,
                                     self.dcfg.xy_tolerance_m, self.dcfg.yaw_tolerance_rad)
        self.laser_in_base = robot.laser_in_base
        self.state = "idle"
        self.reason = ""
        self.detail = ""
        self.attempt = 0
        self.error_m: float | None = None
        self.error_deg: float | None = None
        self.attempts_total = 0
        self._goal: Any = None
        self._fix: DockFix | None = None
        self._fix_odom: Pose2D | None = None
        self._fix_at = -math.inf
        self._off_map = ""  # why the last estimate was dropped (off the map's dock)
        self._odom = PoseHistory(400, interpolation="se2")
        self._phase_start = 0.0
        self._from: Pose2D | None = None
        self._started = False
        self._published: tuple[Any, ...] | None = None

    # --- commands (the behaviour tree) -------------------------------------------------------
    @property
    def docked(self) -> bool:
        """On the dock (whether or not it charges)."""
        return self.state == "docked"

    @property
    def busy(self) -> bool:
        """Docking or undocking in progress."""
        return self.state in BUSY_STATES

    def dock(self, reason: str = "", *, from_here: bool = False) -> None:
        """Start docking (nothing when docked or already docking); ``from_here``: skip the
        staging goal and start the final approach where the rover stands (it must be near the
        staging pose, facing the dock: ``curio bench docking``)."""
        if self.docked or self.state in BUSY_STATES[:-1]:
            return
        self.reason = reason
        self.attempt = 0
        self._event("dock.started", reason=reason)
        if from_here:
            self._begin_attempt()
            return
        staging = self.home.staging()
        self._goal = self.navigator.send_goal([*self.home.route(), staging], tag="dock staging")
        self._set("staging", f"going to the dock ({reason})" if reason else "going to the dock")

    def undock(self) -> None:
        """Back out of the dock (nothing unless docked)."""
        if not self.docked:
            return
        self._from = self._odom_now()
        self._phase_start = self.clock.now()
        self._set("undocking", "leaving the dock")

    def cancel(self, why: str = "canceled") -> None:
        """Stop docking or undocking where the rover is."""
        if not self.busy:
            return
        nav = self.navigator
        if self._goal is not None and nav is not None and nav.active is self._goal:
            nav.cancel()
        self._goal = None
        self._stop()
        self._set("idle", f"docking stopped: {why}")

    # --- the loop -----------------------------------------------------------------------------
    async def run(self) -> None:
        """Run at 20 Hz until cancelled."""
        scan_sub = self.bus.subscribe(SCAN, maxsize=1)
        odom_sub = self.bus.subscribe(ODOM, maxsize=64)
        try:
            async for now in self.clock.every(1.0 / RATE_HZ):
                self._take_odom(odom_sub)
                self._take_scan(scan_sub)
                self.step(now)
        finally:
            scan_sub.close()
            odom_sub.close()

    def _take_odom(self, sub: Subscription[Odometry]) -> None:
        for msg in sub.drain():
            self._odom.add(msg.stamp, msg.pose)

    def _take_scan(self, sub: Subscription[LaserScan]) -> None:
        scans = sub.drain()
        if scans and self.state in ("approaching", "waiting", "backing_off"):
            self.on_scan(scans[-1])

    def step(self, now: float) -> None:
        """One cycle of whatever is in progress."""
        if not self._started:
            self._check_start_on_dock()
        if self.state == "staging":
            self._staging()
        elif self.state == "approaching":
            self._approaching(now)
        elif self.state == "waiting":
            self._waiting(now)
        elif self.state == "backing_off":
            self._reverse(now, self._back_off_done, self._after_back_off)
        elif self.state == "undocking":
            self._reverse(now, self._undock_done, self._after_undock)
        elif self.state == "docked":
            self._check_still_docked()
        elif self.state in ("idle", "failed"):
            self._check_put_on_dock()
        self._publish()

    # --- phases -------------------------------------------------------------------------------
    def _staging(self) -> None:
        goal = self._goal
        if goal is None or not goal.done:
            return
        self._goal = None
        if goal.state.value == "preempted":
            # Another goal (the dashboard's) replaced the way to the dock, or it was
            # cancelled: stopped, not failed (the tree decides whether to dock again).
            self._stop()
            self._set("idle", "docking stopped: the way to the dock was replaced or cancelled")
            return
        if goal.state.value != "succeeded":
            why = str(goal.error) if goal.error is not None else goal.state.value
            self._fail(f"could not reach the staging pose: {why}")
            return
        self._event("dock.staging_reached")
        self._begin_attempt()

    def _begin_attempt(self) -> None:
        self.attempt += 1
        self.attempts_total += 1
        self.approach.reset()
        self._fix = None
        self._fix_at = self.clock.now()
        self._off_map = ""
        self._event("dock.attempt", attempt=self.attempt)
        self._set("approaching", f"approaching the dock (attempt {self.attempt})")

    def _approaching(self, now: float) -> None:
        rover = self.rover_in_dock()
        if rover is None:
            if now - self._fix_at > LOST_SIGHT_S:
                self._retry(self._off_map or "the dock is not in sight")
            else:
                self._drive(0.0, 0.0, now)
            return
        step = self.approach.step(rover, now)
        if step.retry:
            self._retry(step.retry)
            return
        if step.done:
            self._drive(0.0, 0.0, now, close=True)
            self._phase_start = now
            self._set("waiting", "on the dock: waiting for the charger")
            return
        self._drive(step.linear_mps, step.angular_radps, now, close=step.phase == "final")

    def _waiting(self, now: float) -> None:
        self._drive(0.0, 0.0, now, close=True)
        rover = self.rover_in_dock()
        charger = self._charger_v()
        touching = charger is not None and charger > self.cfg.power.charger_detect_v
        if rover is not None:
            self.error_m = round(math.hypot(rover.x, rover.y), 4)
            self.error_deg = round(abs(math.degrees(wrap_angle(rover.yaw))), 3)
        within = (rover is not None and math.hypot(rover.x, rover.y) <= self.dcfg.xy_tolerance_m
                  and abs(wrap_angle(rover.yaw)) <= self.dcfg.yaw_tolerance_rad)
        if touching or (charger is None and within):
            self._stop()
            self._event("dock.docked", attempts=self.attempt, error_m=self.error_m,
                        error_deg=self.error_deg, charging=touching, reason=self.reason)
            self._set("docked", "docked, charging" if touching else "docked")
            return
        if now - self._phase_start >= self.dcfg.contact_wait_s:
            self._retry("no charging voltage on the contacts (missed contact)"
                        if charger is not None else "docked pose out of tolerance")

    def _retry(self, why: str) -> None:
        self._event("dock.retry", attempt=self.attempt, reason=why)
        if self.attempt >= self.dcfg.max_attempts:
            self._fail(f"{why}; gave up after {self.attempt} attempts")
            return
        self._from = self._odom_now()
        self._phase_start = self.clock.now()
        self._set("backing_off", f"backing off to try again: {why}")

    def _back_off_done(self) -> bool:
        rover = self.rover_in_dock()
        if rover is not None:
            return rover.x <= BACK_OFF_X_M
        return self._travelled() >= abs(BACK_OFF_X_M)

    def _after_back_off(self) -> None:
        self._begin_attempt()

    def _undock_done(self) -> bool:
        return self._travelled() >= self.dcfg.undock_distance_m

    def _after_undock(self) -> None:
        self._event("dock.undocked")
        self._set("idle", "left the dock")

    def _reverse(self, now: float, done: Any, after: Any) -> None:
        if done():
            self._stop()
            after()
            return
        speed = self.dcfg.undock_speed_mps
        limit = 3.0 * (self.dcfg.undock_distance_m + abs(BACK_OFF_X_M)) / speed + 5.0
        if now - self._phase_start > limit:
            self._fail("could not back away from the dock (something is behind the rover?)")
            return
        self._drive(-speed, 0.0, now)

    def _fail(self, why: str) -> None:
        self._stop()
        self._event("dock.failed", reason=why, attempts=self.attempt)
        log.warning("docking failed: %s", why)
        self._set("failed", f"docking failed: {why}")

    # --- where the dock is ----------------------------------------------------------------------
    def on_scan(self, scan: LaserScan) -> DockFix | None:
        """Fit the dock in one scan (tracking the last fix, else where the map puts it)."""
        odom = self._odom.at(scan.stamp) if self._odom else None
        guess = self._guess(odom)
        if guess is None:
            return None
        fix = self.detector.detect(scan.points(self.laser_in_base), guess)
        if fix is None or fix.rms_m > 0.03 or not self._agrees_with_map(fix.dock_in_base):
            return None
        if self._fix is not None and fix.shift_m < 0.05:
            # Smooth: move the tracked estimate part of the way to the new fix (single fixes
            # scatter by a centimetre or two with the lidar's range noise).
            d = fix.dock_in_base.relative_to(guess)
            blended = guess @ Pose2D(FIX_GAIN * d.x, FIX_GAIN * d.y, FIX_GAIN * d.yaw)
            fix = DockFix(blended, fix.rms_m, fix.inliers, fix.shift_m, fix.shift_rad)
        self._fix, self._fix_odom, self._fix_at = fix, odom, scan.stamp
        return fix

    def _guess(self, odom_at_scan: Pose2D | None) -> Pose2D | None:
        """The dock in ``base_link`` at a scan: the last fix moved by odometry, or the map's."""
        if self._fix is not None and self._fix_odom is not None and odom_at_scan is not None:
            delta = self._fix_odom.inverse() @ odom_at_scan
            return delta.inverse() @ self._fix.dock_in_base
        pose = self.bus.latest(POSE)
        return None if pose is None else self._map_dock_in_base(pose.pose)

    def _map_dock_in_base(self, pose_in_map: Pose2D) -> Pose2D:
        """The dock in ``base_link`` where the map puts it, the rover at ``pose_in_map``."""
        return pose_in_map.inverse() @ self.home.pose()

    def rover_in_dock(self) -> Pose2D | None:
        """The rover in the dock frame now (the last fix moved by odometry), or None."""
        if self._fix is None or self._fix_odom is None:
            return None
        now = self._odom_now()
        if now is None:
            return self._fix.rover_in_dock()
        rover = self._fix.rover_in_dock() @ (self._fix_odom.inverse() @ now)
        if not self._agrees_with_map(rover.inverse()):
            self._fix = None  # the next scans search around the map's dock again
            return None
        return rover

    def _agrees_with_map(self, dock_in_base: Pose2D) -> bool:
        """Whether a dock estimate (``base_link``, now) lies where the map and the localisation
        put the dock: within ``dock.detect_range_m`` (or 3 σ of ``/pose``) and
        :data:`MAP_GATE_RAD` (or 3 σ); without a pose, any estimate does. Notes why not."""
        pose = self.bus.latest(POSE)
        if pose is None:
            return True
        off = dock_in_base.relative_to(self._map_dock_in_base(pose.pose))
        cov = pose.covariance
        gate_m = max(self.dcfg.detect_range_m, 3.0 * math.sqrt(max(cov[0], cov[4], 0.0)))
        gate_rad = max(MAP_GATE_RAD, 3.0 * math.sqrt(max(cov[8], 0.0)))
        off_m, off_rad = math.hypot(off.x, off.y), abs(wrap_angle(off.yaw))
        if off_m <= gate_m and off_rad <= gate_rad:
            return True
        self._off_map = (f"the dock's shape was not where the map puts it ({off_m * 100:.0f} cm, "
                         f"{math.degrees(off_rad):.0f}° off)")
        log.debug("docking: dropped a dock estimate: %s", self._off_map)
        return False

    # --- helpers ------------------------------------------------------------------------------
    def _check_start_on_dock(self) -> None:
        pose = self.bus.latest(POSE)
        if pose is None:
            return
        self._started = True
        if self.state == "idle" and self._on_dock(pose.pose):
            self._set("docked", "started on the dock")

    def _on_dock(self, pose: Pose2D) -> bool:
        home = self.home.pose()
        return (pose.distance_to(home) <= ON_DOCK_M
                and abs(wrap_angle(pose.yaw - home.yaw)) <= ON_DOCK_RAD)

    def _check_still_docked(self) -> None:
        pose = self.bus.latest(POSE)
        if pose is not None and pose.pose.distance_to(self.home.pose()) > 3 * ON_DOCK_M:
            self._event("dock.left")
            self._set("idle", "moved off the dock")

    def _check_put_on_dock(self) -> None:
        charger = self._charger_v()
        if charger is not None and charger > self.cfg.power.charger_detect_v:
            self._event("dock.docked", attempts=0, error_m=None, error_deg=None, charging=True,
                        reason="put on the dock")
            self._set("docked", "on the dock, charging")

    def _charger_v(self) -> float | None:
        msg = self.bus.latest(BATTERY)
        return msg.charger_v if msg is not None else None

    def _odom_now(self) -> Pose2D | None:
        latest = self._odom.latest()
        return latest[1] if latest is not None else None

    def _travelled(self) -> float:
        now, start = self._odom_now(), self._from
        if now is None or start is None:
            return 0.0
        return now.distance_to(start)

    def _drive(self, v: float, w: float, now: float, close: bool = False) -> None:
        """Command ``(v, w)``; ``close``: creeping onto the dock, the safety stage may let
        the rover close on it (elsewhere its stop zone applies as always)."""
        if close and self.safety is not None:
            self.safety.allow_docking(now + 0.3, self.dcfg.approach_speed_mps)
        self.bus.publish(CMD_VEL_NAV, Twist(now, v, w, source="docking"))

    def _stop(self) -> None:
        self.bus.publish(CMD_VEL_NAV, Twist(self.clock.now(), 0.0, 0.0, source="docking"))

    def _event(self, kind: str, **detail: Any) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, detail))

    def _set(self, state: str, detail: str) -> None:
        self.state = state
        self.detail = detail
        self._publish()

    def to_state(self) -> DockState:
        """The current state as a message."""
        charging = False
        msg = self.bus.latest(BATTERY)
        if msg is not None and msg.charger_v is not None:
            charging = msg.charger_v > self.cfg.power.charger_detect_v
        return DockState(self.clock.now(), self.state, self.attempt, self.error_m,
                         self.error_deg, charging and self.state == "docked", self.detail)

    def _publish(self) -> None:
        state = self.to_state()
        key = (state.state, state.attempt, state.error_m, state.error_deg, state.charging,
               state.detail)
        if key != self._published:
            self._published = key
            self.bus.publish(DOCK, state)
