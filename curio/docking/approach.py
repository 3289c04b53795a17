"""The final approach to the dock: a pure control law on the rover's pose in the dock frame.

Curio turns in place, so the approach is done in straight pieces, not one long curve (its
corner servos swing 180° on arcs tighter than 0.235 m, hardware.md §2.2):

1. ``align_entry`` — turn in place to face the *entry point* ``(ENTRY_X_M, 0)`` on the dock's
   axis (a staging error of 0.3 m and 15° is taken out here);
2. ``to_entry`` — drive straight to it (heading corrected on the way);
3. ``align`` — turn in place onto the axis (heading 0);
4. ``final`` — creep in along the axis (pure pursuit on the line ``y = 0`` with a short
   lookahead, curvature limited), slowing to ``min_speed`` as the stop line ``x = 0`` nears;
   stop on it.

Between a turn and a drive the rover pauses ``SETTLE_S`` (the steering servos swing). A rover
that starts near the axis and well aligned goes straight to ``final``. When the remaining
distance cannot take out the lateral or heading error (less than ``LATE_M`` to go), the step
asks for a retry (back off and approach again); so does a rover that starts past the entry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from curio.core.geometry import Pose2D, wrap_angle

__all__ = ["ENTRY_X_M", "ApproachStep", "DockApproach"]

ENTRY_X_M = -0.30      # the entry point on the dock's axis (turning there clears the dock)
SETTLE_S = 0.3
LOOKAHEAD_M = 0.25
MAX_CURVATURE = 2.0    # 1/m: radius >= 0.5 m while creeping in
LATE_M = 0.08
TURN_MAX_RADPS = 0.4
TURN_MIN_RADPS = 0.06
ALIGN_RAD = 0.012


@dataclass(frozen=True)
class ApproachStep:
    """One command: forward speed (m/s), yaw rate (rad/s), the phase; ``done`` when on the
    stop line, ``retry`` (a reason) when this approach cannot succeed."""

    linear_mps: float
    angular_radps: float
    phase: str
    done: bool = False
    retry: str = ""


class DockApproach:
    """The approach's state (see the module docstring).

    Args:
        max_speed_mps, min_speed_mps: the creeping speed range.
        xy_tolerance_m, yaw_tolerance_rad: the docked pose's tolerance (retry beyond).
    """

    def __init__(self, max_speed_mps: float, min_speed_mps: float, xy_tolerance_m: float,
                 yaw_tolerance_rad: float) -> None:
        self.max_speed_mps = max_speed_mps
        self.min_speed_mps = min(min_speed_mps, max_speed_mps)
        self.xy_tolerance_m = xy_tolerance_m
        self.yaw_tolerance_rad = yaw_tolerance_rad
        self.phase = ""
        self._settle_until = -math.inf

    def reset(self) -> None:
        """A new approach."""
        self.phase = ""
        self._settle_until = -math.inf

    def _enter(self, phase: str, now_s: float) -> None:
        self.phase = phase
        self._settle_until = now_s + SETTLE_S

    def _start(self, r: Pose2D, now_s: float) -> ApproachStep | None:
        if r.x > ENTRY_X_M + 0.05:
            return ApproachStep(0.0, 0.0, "start", retry="too close to the dock to start")
        near_axis = abs(r.y) <= 0.5 * self.xy_tolerance_m + 0.01 and abs(wrap_angle(r.yaw)) \
            <= 0.05
        self._enter("final" if near_axis else "align_entry", now_s)
        return None

    @staticmethod
    def _turn(err: float) -> float:
        w = max(TURN_MIN_RADPS, min(TURN_MAX_RADPS, 1.5 * abs(err)))
        return math.copysign(w, err)

    def step(self, r: Pose2D, now_s: float) -> ApproachStep:
        """The command for the rover at ``r`` (``base_link`` in the dock frame) at ``now_s``."""
        if not self.phase:
            out = self._start(r, now_s)
            if out is not None:
                return out
        if now_s < self._settle_until:
            return ApproachStep(0.0, 0.0, self.phase)
        if self.phase == "align_entry":
            dx, dy = ENTRY_X_M - r.x, -r.y
            if math.hypot(dx, dy) < 0.02:
                self._enter("align", now_s)
                return ApproachStep(0.0, 0.0, self.phase)
            err = wrap_angle(math.atan2(dy, dx) - r.yaw)
            if abs(err) < ALIGN_RAD:
                self._enter("to_entry", now_s)
                return ApproachStep(0.0, 0.0, self.phase)
            return ApproachStep(0.0, self._turn(err), self.phase)
        if self.phase == "to_entry":
            return self._to_entry(r, now_s)
        if self.phase == "align":
            err = wrap_angle(-r.yaw)
            if abs(err) < ALIGN_RAD:
                self._enter("final", now_s)
                return ApproachStep(0.0, 0.0, self.phase)
            return ApproachStep(0.0, self._turn(err), self.phase)
        return self._final(r)

    def _to_entry(self, r: Pose2D, now_s: float) -> ApproachStep:
        dx, dy = ENTRY_X_M - r.x, -r.y
        dist = math.hypot(dx, dy)
        bearing = math.atan2(dy, dx)
        err = wrap_angle(bearing - r.yaw)
        ahead = math.cos(err) * dist  # along the heading
        if dist < 0.01 or ahead <= 0.0:
            self._enter("align", now_s)
            return ApproachStep(0.0, 0.0, self.phase)
        v = min(0.12, max(self.min_speed_mps, 0.6 * ahead))
        w = max(-MAX_CURVATURE * v, min(MAX_CURVATURE * v, 2.0 * err * v / max(dist, 0.05)))
        return ApproachStep(v, w, self.phase)

    def _final(self, r: Pose2D) -> ApproachStep:
        togo = -r.x
        yaw = wrap_angle(r.yaw)
        if togo <= 0.002:
            return ApproachStep(0.0, 0.0, "final", done=True)
        if togo < LATE_M and (abs(r.y) > 2.0 * self.xy_tolerance_m
                              or abs(yaw) > 2.0 * self.yaw_tolerance_rad):
            return ApproachStep(0.0, 0.0, "final", retry=(
                f"off the dock's axis by {r.y * 100:.1f} cm, {math.degrees(yaw):.1f}° with "
                f"{togo * 100:.0f} cm to go"))
        v = max(self.min_speed_mps, min(self.max_speed_mps, 0.5 * togo))
        # Pure pursuit on the axis: the point LOOKAHEAD_M ahead of the rover's projection.
        tx, ty = r.x + LOOKAHEAD_M, 0.0
        c, s = math.cos(r.yaw), math.sin(r.yaw)
        lx = c * (tx - r.x) + s * (ty - r.y)
        ly = -s * (tx - r.x) + c * (ty - r.y)
        kappa = 2.0 * ly / max(lx * lx + ly * ly, 1e-6)
        kappa = max(-MAX_CURVATURE, min(MAX_CURVATURE, kappa))
        return ApproachStep(v, v * kappa, "final")
