"""Recovery actions tried before a goal is given up (move_base's recoveries, for Curio).

The ladder is configurable (``nav.recovery.ladder``); the navigator runs one rung each time
the rover is stuck and climbs to the next rung when that did not help:

* ``clear_costmap`` — forget obstacle-layer marks within ``clear_radius_m`` of the rover
  (stale marks of something that has gone away); the static map stays.
* ``step_back`` — reverse up to ``step_back_distance_m`` at ``step_back_speed_mps`` (the
  original's steer_drive "step back", original-system.md §6.7), stopping as soon as anything
  is within ``step_back_clearance_m`` behind the footprint (from the latest scan) or after
  ``step_back_timeout_s``. Distance is measured from odometry.
* ``rotate`` — turn in place by ``rotate_angle_rad`` towards the side where the swept footprint
  stays clear in the costmap (left first, then right); skipped when neither side has room.
* ``wait`` — hold still for ``wait_s`` (a person or a door may move).

Velocity commands go to ``/cmd_vel_nav`` at ``rate_hz`` and therefore through the safety stage.
Every action returns a :class:`RecoveryOutcome` (what it did, whether it could).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import RecoveryConfig
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import Event, Twist
from curio.core.topics import CMD_VEL_NAV, EVENTS, ODOM, POSE, SCAN
from curio.nav.costs import LETHAL, CostGrid
from curio.robot import RobotModel

__all__ = ["Recovery", "RecoveryOutcome", "points_behind_distance_m"]

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RecoveryOutcome:
    """The result of one recovery action.

    Attributes:
        name: the ladder step.
        ok: whether it could do what it is for (a skipped rotate is not ok).
        detail: a sentence for the operator and the report.
    """

    name: str
    ok: bool
    detail: str = ""


def points_behind_distance_m(points_base: F64, footprint: F64, corridor_margin_m: float = 0.02
                             ) -> float:
    """Distance from the footprint's rear edge to the nearest point straight behind it, m.

    Points are in ``base_link``; "behind" means within the footprint's width (plus a margin)
    and at x below the rear edge. Returns ``inf`` when nothing is there.
    """
    if points_base.size == 0:
        return math.inf
    rear = float(footprint[:, 0].min())
    half = float(np.abs(footprint[:, 1]).max()) + corridor_margin_m
    sel = (points_base[:, 0] < rear) & (np.abs(points_base[:, 1]) <= half)
    if not sel.any():
        return math.inf
    return float(rear - points_base[sel, 0].max())


class Recovery:
    """Runs recovery actions on the bus (see the module docstring).

    Args:
        cfg: ``nav.recovery``.
        robot: the robot model (footprint, laser pose).
        clock, bus: injected.
        costmap: the global costmap (clearing and room checks); None skips those.
    """

    def __init__(self, cfg: RecoveryConfig, robot: RobotModel, clock: Clock, bus: Bus,
                 costmap: CostGrid | None) -> None:
        self.cfg = cfg
        self.robot = robot
        self.clock = clock
        self.bus = bus
        self.costmap = costmap
        self.footprint = robot.footprint
        self.running: str | None = None
        self.history: list[RecoveryOutcome] = []

    # --- helpers ----------------------------------------------------------------------------
    def _pose(self) -> Pose2D | None:
        msg = self.bus.latest(POSE)
        return msg.pose if msg is not None else None

    def _odom_pose(self) -> Pose2D | None:
        msg = self.bus.latest(ODOM)
        if msg is not None:
            return msg.pose
        return self._pose()

    def _scan_points(self) -> F64:
        scan = self.bus.latest(SCAN)
        if scan is None:
            return np.zeros((0, 2))
        return scan.points(self.robot.laser_in_base)

    def _send(self, v: float, w: float) -> None:
        self.bus.publish(CMD_VEL_NAV, Twist(self.clock.now(), v, w, source="recovery"))

    def _event(self, outcome: RecoveryOutcome) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), "nav.recovery",
                                       {"step": outcome.name, "ok": outcome.ok,
                                        "detail": outcome.detail}))

    # --- actions ----------------------------------------------------------------------------
    async def run(self, step: str) -> RecoveryOutcome:
        """Run one ladder step and return what happened (cancellable: the rover is stopped)."""
        actions: dict[str, Callable[[], object]] = {
            "clear_costmap": self.clear_costmap,
            "step_back": self.step_back,
            "rotate": self.rotate,
            "wait": self.wait,
        }
        if step not in actions:
            raise ValueError(f"unknown recovery step '{step}'; allowed: {', '.join(actions)}")
        self.running = step
        try:
            if step == "clear_costmap":
                outcome = self.clear_costmap()
            elif step == "step_back":
                outcome = await self.step_back()
            elif step == "rotate":
                outcome = await self.rotate()
            else:
                outcome = await self.wait()
        finally:
            self.running = None
            self._send(0.0, 0.0)
        self.history.append(outcome)
        self._event(outcome)
        return outcome

    def clear_costmap(self) -> RecoveryOutcome:
        """Forget obstacle marks around the rover."""
        pose = self._pose()
        if self.costmap is None or pose is None:
            return RecoveryOutcome("clear_costmap", False, "no costmap or no pose to clear around")
        self.costmap.clear_around(pose, self.cfg.clear_radius_m)
        return RecoveryOutcome("clear_costmap", True,
                               f"cleared obstacle marks within {self.cfg.clear_radius_m:g} m")

    async def step_back(self) -> RecoveryOutcome:
        """Reverse up to ``step_back_distance_m``, stopping for anything close behind."""
        cfg = self.cfg
        start = self._odom_pose()
        if start is None:
            return RecoveryOutcome("step_back", False, "no odometry: cannot measure the reverse")
        t0 = self.clock.now()
        travelled = 0.0
        reason = "reversed the full distance"
        ok = True
        async for now in self.clock.every(1.0 / cfg.rate_hz, immediate=True):
            pose = self._odom_pose() or start
            travelled = pose.distance_to(start)
            if travelled >= cfg.step_back_distance_m:
                break
            behind = points_behind_distance_m(self._scan_points(), self.footprint)
            if behind <= cfg.step_back_clearance_m or self._mapped_obstacle_behind():
                behind = min(behind, cfg.step_back_clearance_m)
                reason = f"stopped: something within {behind:.2f} m behind"
                ok = travelled > 0.05
                break
            if now - t0 > cfg.step_back_timeout_s:
                reason = "stopped: step-back timeout"
                ok = travelled > 0.05
                break
            # Slow down for the last few centimetres so the distance is not overshot.
            left = cfg.step_back_distance_m - travelled
            speed = min(cfg.step_back_speed_mps, max(0.08, 2.0 * left))
            self._send(-speed, 0.0)
        self._send(0.0, 0.0)
        return RecoveryOutcome("step_back", ok, f"{reason} ({travelled:.2f} m)")

    def _mapped_obstacle_behind(self) -> bool:
        """Whether the costmap has an obstacle within the clearance behind the footprint."""
        pose = self._pose()
        if self.costmap is None or pose is None:
            return False
        back = np.linspace(0.05, max(0.05, self.cfg.step_back_clearance_m), 4)
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        poses = np.stack([pose.x - c * back, pose.y - s * back, np.full(len(back), pose.yaw)],
                         axis=1)
        return bool((self.costmap.footprint_costs(poses) >= LETHAL).any())

    def _room_to_rotate(self, pose: Pose2D, angle_rad: float) -> bool:
        if self.costmap is None:
            return True
        n = max(2, int(abs(angle_rad) / 0.1) + 1)
        yaws = pose.yaw + np.linspace(0.0, angle_rad, n)
        poses = np.stack([np.full(n, pose.x), np.full(n, pose.y), yaws], axis=1)
        costs = self.costmap.footprint_costs(poses)
        return bool((costs[1:] < LETHAL).all())

    async def rotate(self) -> RecoveryOutcome:
        """Turn in place by ``rotate_angle_rad`` where the costmap leaves room."""
        cfg = self.cfg
        pose = self._pose()
        if pose is None:
            return RecoveryOutcome("rotate", False, "no pose")
        angle = 0.0
        for candidate in (cfg.rotate_angle_rad, -cfg.rotate_angle_rad):
            if self._room_to_rotate(pose, candidate):
                angle = candidate
                break
        if angle == 0.0:
            return RecoveryOutcome("rotate", False, "no room to turn in place")
        turned = 0.0
        last_yaw = (self._odom_pose() or pose).yaw
        t0 = self.clock.now()
        async for now in self.clock.every(1.0 / cfg.rate_hz, immediate=True):
            yaw = (self._odom_pose() or pose).yaw
            turned += wrap_angle(yaw - last_yaw)
            last_yaw = yaw
            if abs(turned) >= abs(angle) - 0.05:
                break
            if now - t0 > cfg.rotate_timeout_s:
                self._send(0.0, 0.0)
                return RecoveryOutcome("rotate", False,
                                       f"turned {math.degrees(turned):.0f} deg before timeout")
            left = abs(angle) - abs(turned)
            w = math.copysign(min(cfg.rotate_speed_radps, max(0.2, 1.5 * left)), angle)
            self._send(0.0, w)
        self._send(0.0, 0.0)
        return RecoveryOutcome("rotate", True, f"turned {math.degrees(turned):.0f} deg in place")

    async def wait(self) -> RecoveryOutcome:
        """Hold still for ``wait_s``."""
        period = 1.0 / self.cfg.rate_hz
        end = self.clock.now() + self.cfg.wait_s
        # Not a fixed-rate loop: the last sleep is cut short to end exactly at the deadline.
        while self.clock.now() < end:
            self._send(0.0, 0.0)
            await self.clock.sleep(min(period, max(0.0, end - self.clock.now())) or period)
        return RecoveryOutcome("wait", True, f"waited {self.cfg.wait_s:g} s")
