"""The local controller: regulated pure pursuit for Curio, with a sampled fallback.

It follows the global plan (poses in ``map``) from the rover's pose in ``map`` and produces a
body twist (forward m/s, yaw rate rad/s in ``base_link``) at ``nav.controller.rate_hz``:

* **Turn in place** when the heading error to the lookahead point exceeds ``rotate_enter_rad``
  (Curio can; hysteresis down to ``rotate_exit_rad``), and at the goal to meet the yaw
  tolerance.
* **Narrow passages**: where the plan within ``narrow_ahead_m`` passes nearer an obstacle than
  the footprint's circumscribed radius (Curio is nearly square: a misaligned rover may not fit
  where its inscribed circle does), the lookahead drops to ``narrow_lookahead_m`` and the rover
  turns in place above ``narrow_rotate_enter_rad``, so it enters lined up with the centred plan.
* **Pure pursuit** otherwise: curvature ``κ = 2·y / L²`` to the lookahead point at ``L``
  metres along the plan; arcs tighter than ``min_turning_radius_m`` are not driven (Curio's
  corner servos would swing 180° when the radius crosses 0.235 m, hardware.md §2.2); the
  curvature changes at most ``max_curvature_rate_per_s`` per second, and between turning in
  place and driving the rover pauses ``steer_settle_s`` so the servos can swing.
* **Regulation**: speed is limited by the curvature, the clearance to obstacles (the costmap's
  inflation tells the distance; below ``slow_clearance_m`` the speed falls towards
  ``slow_min_fraction``), and a ``sqrt(2·a·d)`` approach profile to the goal; acceleration
  limits ``max_accel_mps2`` / ``max_angular_accel_radps2``.
* **Obstacles not on the map**: the predicted trajectory (``collision_horizon_s``) is checked
  against the costmap (whose obstacle layer follows every scan). When it collides, a small
  set of arcs and in-place turns is sampled and scored (progress to the lookahead point,
  clearance); when none is admissible for ``blocked_timeout_s`` the controller reports
  ``blocked``.
* **Goal checker** (``xy_goal_tolerance_m``, latched, then ``yaw_goal_tolerance_rad``) and a
  **progress checker** (``progress_min_distance_m`` within ``progress_timeout_s``).
* **People** (optional, :attr:`LocalController.people`): a last stage that reviews the arc
  the stages above chose against the predicted motion of tracked people and may slow it,
  bend it, or stop and yield (``curio/people/stage.py``); the controller's own manoeuvres
  (turning in place, making room to turn) wait while they would drive at someone. Without
  it nothing changes.

:meth:`LocalController.compute` is pure computation (no bus, no awaits) so it is unit-tested and
benchmarked directly; the navigator calls it.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
import numpy.typing as npt

from curio.core.config import ControllerConfig
from curio.core.geometry import Pose2D, approach, arc_poses, wrap_angle
from curio.nav.controller_kernels import outline_costs
from curio.nav.costs import (
    INSCRIBED,
    LETHAL,
    NO_INFORMATION,
    CostGrid,
    cost_at_distance,
    distance_beyond_inscribed_m,
)
from curio.robot import RobotModel

__all__ = [
    "ControlOutput",
    "ControlStatus",
    "LocalController",
    "MotionReview",
    "ProgressChecker",
    "Review",
    "lookahead_m",
    "pursuit_curvature",
    "regulated_speed",
    "rollout",
    "rotate_hysteresis",
    "to_base_link",
]

F64 = npt.NDArray[np.float64]

OUTLINE_MARGIN_M = 0.015
# Gentle curvatures (1/m) the make-room manoeuvre tries besides its nine (4 to 10 m radius),
# and how far along each it looks for a place to turn in, metres.
GENTLE_KAPPAS = np.array([-0.25, -0.1, -0.05, 0.05, 0.1, 0.25])
MAKE_ROOM_M = 3.0


class ControlStatus(enum.Enum):
    """What the controller is doing."""

    IDLE = "idle"
    FOLLOWING = "following"
    ROTATING = "rotating"
    AVOIDING = "avoiding"
    GOAL_REACHED = "goal_reached"
    BLOCKED = "blocked"
    NO_PROGRESS = "no_progress"
    YIELDING = "yielding"  # waiting for people to pass (the people stage)


@dataclass
class ControlOutput:
    """One control cycle's result.

    Attributes:
        linear_mps: forward speed, ``base_link``.
        angular_radps: yaw rate, ``base_link``.
        status: what the controller is doing.
        trajectory: predicted poses ``(K, 3)`` (x, y, yaw) in ``map``.
        distance_to_goal_m: straight-line distance to the final pose.
        distance_remaining_m: along the plan from the nearest plan point to its end.
        detail: a short human-readable note (why it slows or stops).
    """

    linear_mps: float
    angular_radps: float
    status: ControlStatus
    trajectory: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    distance_to_goal_m: float = math.inf
    distance_remaining_m: float = math.inf
    detail: str = ""


@dataclass(frozen=True)
class Review:
    """What a reviewing stage makes of the chosen motion.

    Attributes:
        linear_mps: forward speed to command (``base_link``), after its acceleration limits.
        kappa: curvature to drive, 1/m.
        status, detail: what the controller reports.
        hold_progress: the rover waits for people: the progress checks do not count it.
        arrived: treat the goal's position as reached here (people stand on it).
    """

    linear_mps: float
    kappa: float
    status: ControlStatus
    detail: str = ""
    hold_progress: bool = False
    arrived: bool = False


class MotionReview(Protocol):
    """A last stage that may change the arc the controller chose (the people stage)."""

    def review(self, controller: LocalController, pose: Pose2D, now_s: float,
               linear_mps: float, target_mps: float, kappa: float, aim: tuple[float, float],
               kmax: float, dist_goal_m: float) -> Review | None:
        """Keep (None) or replace the motion chosen at ``pose`` (``map``) towards the
        lookahead point ``aim`` (``map``): ``linear_mps`` this cycle (m/s), speeding towards
        ``target_mps``, on curvature ``kappa`` (1/m, at most ``kmax``)."""

    def steering(self, now_s: float) -> bool:
        """Whether the stage is steering round people now (the controller then does not start
        turning in place back to its path: the stage's arcs take it back)."""

    def review_turn(self, pose: Pose2D, now_s: float, turn_rad: float) -> Review | None:
        """None: turning in place at ``pose`` (``map``) by ``turn_rad`` (rad, counter-clockwise
        positive) keeps clear of everyone; else why not (the rover brakes and waits)."""

    def first_too_near(self, poses: F64, step_s: float,
                       now_s: float) -> npt.NDArray[np.int64]:
        """For each arc of ``poses`` ``(M, K, 3)`` (``map``, ``step_s`` apart from now), the
        index of its first pose that drives at someone (``K``: none does)."""

    def wait_for_people(self, now_s: float, detail: str) -> Review:
        """The review for a rover that waits because its own manoeuvre would drive at
        someone."""


class ProgressChecker:
    """Reports no progress when the rover has neither moved ``min_distance_m`` nor turned
    ``min_rotation_rad`` within ``timeout_s`` (clock seconds)."""

    def __init__(self, min_distance_m: float, timeout_s: float,
                 min_rotation_rad: float = 0.5) -> None:
        self.min_distance_m = min_distance_m
        self.min_rotation_rad = min_rotation_rad
        self.timeout_s = timeout_s
        self._ref: Pose2D | None = None
        self._ref_t = 0.0

    def reset(self) -> None:
        """Forget the reference (a new goal, or after a recovery)."""
        self._ref = None

    def update(self, pose: Pose2D, now_s: float) -> bool:
        """Feed a pose; return True while progress is being made (False: stuck)."""
        if self._ref is None:
            self._ref, self._ref_t = pose, now_s
            return True
        moved = pose.distance_to(self._ref)
        turned = abs(wrap_angle(pose.yaw - self._ref.yaw))
        if moved >= self.min_distance_m or turned >= self.min_rotation_rad:
            self._ref, self._ref_t = pose, now_s
            return True
        return now_s - self._ref_t <= self.timeout_s


def rollout(pose: Pose2D, linear_mps: float, angular_radps: float, horizon_s: float,
            dt_s: float) -> F64:
    """Poses ``(K, 3)`` in ``map`` reached by holding a twist, starting with ``pose`` itself."""
    n = max(1, math.ceil(horizon_s / dt_s))
    local = arc_poses(linear_mps, angular_radps, np.arange(n + 1, dtype=np.float64) * dt_s)
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    out = np.empty((n + 1, 3))
    out[:, 0] = pose.x + c * local[:, 0] - s * local[:, 1]
    out[:, 1] = pose.y + s * local[:, 0] + c * local[:, 1]
    out[:, 2] = pose.yaw + local[:, 2]
    return out


def to_base_link(pose: Pose2D, x_m: float, y_m: float) -> tuple[float, float]:
    """A ``map`` point in the rover's frame (``base_link``) at ``pose``."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    dx, dy = x_m - pose.x, y_m - pose.y
    return c * dx + s * dy, -s * dx + c * dy


def lookahead_m(cfg: ControllerConfig, dist_goal_m: float, narrow: bool) -> tuple[float, float]:
    """The lookahead distance (m) and the heading error above which to turn in place (rad):
    ``lookahead_m`` (no nearer than ``min_lookahead_m``, no farther than the goal) and
    ``rotate_enter_rad``; ``narrow_lookahead_m`` and ``narrow_rotate_enter_rad`` at most
    before a ``narrow`` passage."""
    lookahead = max(cfg.min_lookahead_m, min(cfg.lookahead_m, dist_goal_m))
    rotate_enter = cfg.rotate_enter_rad
    if narrow:
        lookahead = min(lookahead, cfg.narrow_lookahead_m)
        rotate_enter = min(rotate_enter, cfg.narrow_rotate_enter_rad)
    return lookahead, rotate_enter


def rotate_hysteresis(rotating: bool, heading_err_rad: float, enter_rad: float,
                      exit_rad: float) -> bool:
    """Whether to turn in place: start above ``enter_rad`` (never below ``exit_rad``) of
    heading error, keep turning until it is under ``exit_rad``."""
    if rotating:
        return not abs(heading_err_rad) < exit_rad
    return abs(heading_err_rad) > max(enter_rad, exit_rad)


def pursuit_curvature(x_r: float, y_r: float, kmax: float) -> float:
    """Pure pursuit: the curvature (1/m) of the arc through the lookahead point ``(x_r, y_r)``
    in ``base_link``, ``2·y / L²``, clamped to ``±kmax``."""
    l2 = x_r * x_r + y_r * y_r
    kappa = 2.0 * y_r / l2 if l2 > 1e-9 else 0.0
    return max(-kmax, min(kmax, kappa))


def regulated_speed(cfg: ControllerConfig, robot: RobotModel, kappa: float, clearance_m: float,
                    dist_goal_m: float, settling: bool) -> tuple[float, str]:
    """The target forward speed (m/s) on an arc of curvature ``kappa`` and why it is lower
    than ``max_speed_mps``: the fastest wheel, the yaw-rate limit, the clearance to
    obstacles, the approach profile to the goal, the steering servos ``settling``."""
    detail = ""
    # Fastest wheel on this arc (hardware.md §2.2): |v|·max hypot(x κ, 1 − y κ).
    v_target = min(cfg.max_speed_mps, robot.max_speed_on_arc_mps(kappa))
    # Angular limit on the arc.
    if abs(kappa) > 1e-9:
        v_target = min(v_target, cfg.max_angular_radps / abs(kappa))
    if clearance_m < cfg.slow_clearance_m and cfg.slow_clearance_m > 0:
        frac = max(cfg.slow_min_fraction, clearance_m / cfg.slow_clearance_m)
        v_target *= frac
        detail = "near an obstacle"
    d_stop = max(0.0, dist_goal_m - 0.5 * cfg.xy_goal_tolerance_m)
    v_goal = math.sqrt(2.0 * cfg.approach_decel_mps2 * d_stop)
    if v_goal < v_target:
        v_target = max(cfg.min_speed_mps, v_goal)
        detail = detail or "approaching the goal"
    if settling:
        v_target = 0.0
        detail = "steering servos settling"
    return v_target, detail


@dataclass(frozen=True)
class _Cycle:
    """Where one control cycle finds the rover: ``pose`` in ``map`` at clock ``now_s``, the
    nearest plan index ``i``, straight-line and along-plan distances to the goal (m)."""

    pose: Pose2D
    now_s: float
    i: int
    dist_goal: float
    remaining: float


@dataclass(frozen=True)
class _Aim:
    """Where the rover steers: the lookahead ``point`` in ``map``, the same in ``base_link``
    (``x_r``, ``y_r``), the heading error to it and the turn-in-place threshold (rad)."""

    point: tuple[float, float]
    x_r: float
    y_r: float
    heading_err: float
    rotate_enter_rad: float


class LocalController:
    """Regulated pure pursuit with in-place turns, for Curio (see the module docstring).

    Args:
        cfg: ``nav.controller``.
        robot: the robot model (the fastest-wheel speed on an arc).
        costmap: cost lookups for collision checks and clearance (its padded footprint and
            cost scaling); None disables them.
    """

    def __init__(self, cfg: ControllerConfig, robot: RobotModel,
                 costmap: CostGrid | None = None) -> None:
        self.cfg = cfg
        self.robot = robot
        self.costmap = costmap
        self.dt_s = 1.0 / cfg.rate_hz
        self.plan: F64 = np.zeros((0, 3))
        self._cum: F64 = np.zeros(0)
        self.goal: Pose2D | None = None
        self.check_yaw = True
        self.progress = ProgressChecker(cfg.progress_min_distance_m, cfg.progress_timeout_s)
        # Speed limits for the rover at a pose in map (m/s), by the reason shown when one
        # binds: the speed zones (curio/zones), a rover giving way (curio/fleet/traffic.py).
        self.speed_limits: dict[str, Callable[[Pose2D], float]] = {}
        self.people: MotionReview | None = None  # the people stage (curio/people/wiring.py)
        self.reset()

    # --- state ------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the motion state (call when a goal starts or after a recovery moved us)."""
        self._v = 0.0
        self._w = 0.0
        self._kappa = 0.0
        self._rotating = False
        self._settle_until = -math.inf
        self._xy_reached = False
        self._index = 0
        self._blocked_since: float | None = None
        self._room_until = -math.inf
        self._room_kappa = 0.0
        self._room_v = -self.REVERSE_SPEED_MPS
        self._reverses = 0
        self._best_remaining = math.inf
        self.progress.reset()

    def set_plan(self, poses: F64 | list[Pose2D], goal: Pose2D | None = None,
                 check_yaw: bool = True) -> None:
        """Follow a new plan (``(N, 3)`` array or poses, ``map``) to ``goal`` (default: its end).

        The goal checker's latch and the motion state are kept, so replanning is seamless.
        """
        if isinstance(poses, list):
            arr = np.array([[p.x, p.y, p.yaw] for p in poses], dtype=np.float64).reshape(-1, 3)
        else:
            arr = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        new_goal = goal if goal is not None else (
            Pose2D(*arr[-1]) if len(arr) else None)
        if self.goal is None or new_goal is None or new_goal.distance_to(self.goal) > 1e-6 \
                or abs(wrap_angle(new_goal.yaw - self.goal.yaw)) > 1e-6:
            self._xy_reached = False
        self.goal = new_goal
        self.check_yaw = check_yaw and new_goal is not None and math.isfinite(new_goal.yaw)
        self.plan = arr
        if len(arr) > 1:
            seg = np.hypot(np.diff(arr[:, 0]), np.diff(arr[:, 1]))
            self._cum = np.concatenate([[0.0], np.cumsum(seg)])
        else:
            self._cum = np.zeros(len(arr))
        self._index = 0

    @property
    def commanded_mps(self) -> float:
        """The forward speed commanded in the last cycle (m/s, ``base_link``)."""
        return self._v

    @property
    def plan_index(self) -> int:
        """Index of the plan pose nearest the rover at the last cycle (the plan before it is
        behind the rover)."""
        return self._index

    def clear_plan(self) -> None:
        """Stop following (the next compute returns IDLE and zero)."""
        self.plan = np.zeros((0, 3))
        self._cum = np.zeros(0)
        self.goal = None

    # --- helpers ----------------------------------------------------------------------------
    def _nearest_index(self, pose: Pose2D) -> int:
        """Nearest plan index, searched forward from the last one (the plan is pruned)."""
        plan = self.plan
        lo = self._index
        hi = min(len(plan), lo + 200)
        d = np.hypot(plan[lo:hi, 0] - pose.x, plan[lo:hi, 1] - pose.y)
        i = lo + int(np.argmin(d))
        if d.min() > 1.0:  # lost the thread (e.g. after a recovery): search everything
            dall = np.hypot(plan[:, 0] - pose.x, plan[:, 1] - pose.y)
            i = int(np.argmin(dall))
        self._index = i
        return i

    def _lookahead_point(self, pose: Pose2D, i: int, lookahead_m: float) -> tuple[float, float]:
        plan = self.plan
        d = np.hypot(plan[i:, 0] - pose.x, plan[i:, 1] - pose.y)
        beyond = np.nonzero(d >= lookahead_m)[0]
        if len(beyond) == 0:
            return float(plan[-1, 0]), float(plan[-1, 1])
        j = i + int(beyond[0])
        if j > i:  # interpolate on the segment that crosses the circle
            p0, p1 = plan[j - 1, :2], plan[j, :2]
            d0, d1 = d[j - 1 - i], d[j - i]
            t = 0.0 if d1 == d0 else (lookahead_m - d0) / (d1 - d0)
            t = min(1.0, max(0.0, t))
            q = p0 + t * (p1 - p0)
            return float(q[0]), float(q[1])
        return float(plan[j, 0]), float(plan[j, 1])

    def _clearance_m(self, pose: Pose2D) -> float:
        """Distance from the footprint to the nearest obstacle, estimated from the centre cost
        (the inverse of the inflation: a lower bound of the flank clearance)."""
        if self.costmap is None:
            return math.inf
        return distance_beyond_inscribed_m(self.costmap.cost_at(pose.x, pose.y),
                                           self.costmap.cost_scaling_factor)

    def _narrow_threshold(self, cm: CostGrid) -> int:
        """Centre cost at the circumscribed radius from an obstacle."""
        if self._narrow_cost is None:
            self._narrow_cost = int(cost_at_distance(
                cm.circumscribed_radius_m - cm.inscribed_radius_m, cm.cost_scaling_factor))
        return self._narrow_cost

    _narrow_cost: int | None = None

    def _narrow_ahead(self, i: int) -> bool:
        """Whether the plan within ``narrow_ahead_m`` of index ``i`` passes nearer an obstacle
        than the footprint's circumscribed radius (a misaligned rover may not fit there)."""
        cm = self.costmap
        if cm is None or self.cfg.narrow_ahead_m <= 0.0:
            return False
        cum = self._cum
        j = int(np.searchsorted(cum, cum[i] + self.cfg.narrow_ahead_m, side="right"))
        ahead = self.plan[i:max(j, i + 1)]
        grid = cm.costs()
        res = float(cm.resolution_m)
        gxy = cm.origin.inverse().transform_points(ahead[:, :2])
        cols = np.floor(gxy[:, 0] / res).astype(np.int64)
        rows = np.floor(gxy[:, 1] / res).astype(np.int64)
        h, w = grid.shape
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        vals = grid[rows[inside], cols[inside]]
        vals = vals[vals != NO_INFORMATION]
        return bool(len(vals) and int(vals.max()) >= self._narrow_threshold(cm))

    def _perimeter(self, cm: CostGrid) -> F64:
        """Points every half cell along the (padded) footprint's edges, ``base_link``."""
        if self._perimeter_pts is None:
            poly = np.asarray(cm.footprint, dtype=np.float64).reshape(-1, 2)
            # A little extra so a graze between the outline's samples is still seen.
            poly = poly + np.sign(poly) * OUTLINE_MARGIN_M
            step = 0.5 * float(cm.resolution_m)
            pts = []
            for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
                n = max(2, math.ceil(float(np.hypot(*(b - a))) / step) + 1)
                t = np.linspace(0.0, 1.0, n, endpoint=False)[:, None]
                pts.append(a + t * (b - a))
            self._perimeter_pts = np.concatenate(pts, axis=0)
        return self._perimeter_pts

    _perimeter_pts: F64 | None = None

    def trajectory_costs(self, trajs: F64, coarse: bool = False) -> npt.NDArray[np.uint8]:
        """Max cost under the footprint's outline for each pose of ``(M, K, 3)`` trajectories
        (``coarse``: every other outline sample, a cell apart, for a search over many long
        arcs whose chosen arc is checked in full as it is driven).

        Only the outline is sampled: between poses a few centimetres apart, nothing can get
        inside the footprint without crossing it. Off-grid poses count as lethal.
        """
        cm = self.costmap
        assert cm is not None
        grid = cm.costs()
        res = float(cm.resolution_m)
        origin = cm.origin
        per = self._perimeter(cm)
        if coarse:
            per = per[::2]
        trajs = np.asarray(trajs, dtype=np.float64)
        c, s = np.cos(trajs[..., 2:3]), np.sin(trajs[..., 2:3])
        out = np.empty(trajs.shape[:2], dtype=np.uint8)
        rotated = origin.yaw != 0.0
        oc, os_ = (math.cos(origin.yaw), math.sin(origin.yaw)) if rotated else (1.0, 0.0)
        outline_costs(grid, trajs, c, s, per, float(origin.x), float(origin.y), rotated,
                      oc, os_, res, int(LETHAL), out)
        return out

    def _collides(self, traj: F64) -> tuple[bool, int]:
        """Whether a trajectory's footprint hits a lethal or unknown cell (after its start)."""
        if self.costmap is None:
            return False, 0
        costs = self.trajectory_costs(traj[None])[0]
        if costs[0] >= LETHAL:
            # Already touching a mark (noise, a tight gap): only forbid going deeper.
            return False, int(costs[0])
        return bool((costs[1:] >= LETHAL).any()), int(costs.max())

    # --- the control law: a pipeline of stages -------------------------------------------
    def compute(self, pose: Pose2D, now_s: float,
                velocity: tuple[float, float] | None = None) -> ControlOutput:
        """One control cycle from the rover's ``pose`` in ``map`` at clock time ``now_s``.

        ``velocity`` (measured v, ω) is accepted for interface symmetry; the controller uses
        its own last command as the state of its acceleration limits (open loop, as the safety
        stage).

        The stages: where the rover is on the plan (:meth:`_track`); at the goal, turn to the
        final heading (:meth:`_final_heading`); otherwise choose the lookahead point
        (:meth:`_aim`, shorter before a narrow passage), decide whether to turn in place
        (:func:`rotate_hysteresis`), and either go on backing out, turn in place
        (:meth:`_rotate_in_place`) or follow the arc (:meth:`_pursue`: pure pursuit, speed
        regulation, then :meth:`_guard`: collision check, sampled avoidance, reversing).
        """
        if self.goal is None or len(self.plan) == 0:
            self._v = self._w = 0.0
            return ControlOutput(0.0, 0.0, ControlStatus.IDLE)
        cyc = self._track(pose, now_s)
        if self._xy_reached:
            return self._final_heading(cyc, self.goal)
        aim = self._aim(cyc)
        rotating = rotate_hysteresis(self._rotating, aim.heading_err, aim.rotate_enter_rad,
                                     self.cfg.rotate_exit_rad)
        if rotating and not self._rotating and self.people is not None and \
                self.people.steering(now_s):
            rotating = False
        if self._rotating and not rotating:
            self._settle_until = now_s + self.cfg.steer_settle_s
        self._rotating = rotating
        if now_s < self._room_until:
            out = self._continue_making_room(cyc)
            if out is not None:
                return out
        if self._rotating:
            return self._rotate_in_place(cyc, aim)
        return self._pursue(cyc, aim)

    def _track(self, pose: Pose2D, now_s: float) -> _Cycle:
        """Stage 0: the nearest plan pose, the distances left, the goal checker's xy latch."""
        assert self.goal is not None
        dist_goal = pose.distance_to(self.goal)
        i = self._nearest_index(pose)
        remaining = float(self._cum[-1] - self._cum[i]) + float(
            math.hypot(self.plan[i, 0] - pose.x, self.plan[i, 1] - pose.y))
        if remaining < self._best_remaining - 0.3:
            self._best_remaining = remaining
            self._reverses = 0
        if dist_goal <= self.cfg.xy_goal_tolerance_m:
            self._xy_reached = True
        return _Cycle(pose, now_s, i, dist_goal, remaining)

    def _final_heading(self, cyc: _Cycle, goal: Pose2D) -> ControlOutput:
        """Stage 1, at the goal: turn in place to its heading, then report it reached."""
        yaw_err = wrap_angle(goal.yaw - cyc.pose.yaw) if self.check_yaw else 0.0
        if abs(yaw_err) <= self.cfg.yaw_goal_tolerance_rad:
            self._v = self._w = 0.0
            return ControlOutput(0.0, 0.0, ControlStatus.GOAL_REACHED,
                                 distance_to_goal_m=cyc.dist_goal, distance_remaining_m=0.0)
        held = self._people_hold_turn(replace(cyc, remaining=0.0), yaw_err)
        if held is not None:
            return held
        v, w = self._turn(yaw_err)
        return self._finish(replace(cyc, remaining=0.0), v, w, ControlStatus.ROTATING,
                            "final heading")

    def _aim(self, cyc: _Cycle) -> _Aim:
        """Stage 2: the lookahead point (short in and before a narrow passage: track the
        centred plan tightly and turn in place sooner, so the square footprint enters
        aligned), in ``base_link``."""
        lookahead, rotate_enter = lookahead_m(self.cfg, cyc.dist_goal, self._narrow_ahead(cyc.i))
        lx, ly = self._lookahead_point(cyc.pose, cyc.i, lookahead)
        x_r, y_r = to_base_link(cyc.pose, lx, ly)
        return _Aim((lx, ly), x_r, y_r, math.atan2(y_r, x_r), rotate_enter)

    def _rotate_in_place(self, cyc: _Cycle, aim: _Aim) -> ControlOutput:
        """Stage 3: turn towards the lookahead point; where the corners cannot swing round,
        back out to make room (or report blocked)."""
        if abs(self._v) < 1e-3 and self._rotation_blocked(cyc.pose, aim.heading_err):
            return self._make_room(cyc, aim.point) or self._blocked(cyc)
        held = self._people_hold_turn(cyc, aim.heading_err)
        if held is not None:
            return held
        v, w = self._turn(aim.heading_err)
        return self._finish(cyc, v, w, ControlStatus.ROTATING, "turning towards the path")

    def _pursue(self, cyc: _Cycle, aim: _Aim) -> ControlOutput:
        """Stage 4: pure pursuit on the arc to the lookahead point at the regulated speed,
        within the curvature-rate and acceleration limits."""
        cfg = self.cfg
        kmax = 1.0 / cfg.min_turning_radius_m if cfg.min_turning_radius_m > 0 else 1e9
        kappa = pursuit_curvature(aim.x_r, aim.y_r, kmax)
        v_target, detail = regulated_speed(cfg, self.robot, kappa, self._clearance_m(cyc.pose),
                                           cyc.dist_goal, cyc.now_s < self._settle_until)
        for reason, limit_at in self.speed_limits.items():
            limit = limit_at(cyc.pose)
            if limit < v_target:
                v_target, detail = limit, detail or reason
        if abs(self._v) < 1e-3 and abs(self._w) < 1e-3:
            self._kappa = kappa  # standing still: the servos swing while the speed ramps up
        else:
            self._kappa = approach(self._kappa, kappa, cfg.max_curvature_rate_per_s * self.dt_s)
        v = approach(self._v, v_target, cfg.max_accel_mps2 * self.dt_s)
        return self._guard(cyc, aim, kmax, v, v_target, detail)

    def _guard(self, cyc: _Cycle, aim: _Aim, kmax: float, v: float, v_target: float,
               detail: str) -> ControlOutput:
        """Stage 5: check the arc against the costmap; when it collides, drive the best
        sampled arc instead, or back out, or report blocked."""
        cfg = self.cfg
        w = v * self._kappa
        status = ControlStatus.FOLLOWING
        # Check the arc over a distance, not a time: creeping slowly must not make it look safe.
        check_v = max(v, v_target, 0.5 * cfg.max_speed_mps)
        traj = rollout(cyc.pose, check_v, check_v * self._kappa, cfg.collision_horizon_s, 0.1)
        hit, _ = self._collides(traj)
        if hit:
            alt = self._sample(cyc.pose, aim.x_r, aim.y_r, kmax)
            if alt is None:
                if abs(self._v) < 0.05 and abs(aim.heading_err) > cfg.rotate_exit_rad:
                    out = self._make_room(cyc, aim.point)
                    if out is not None:
                        return out
                return self._blocked(cyc)
            v_alt, k_alt = alt
            v_target = v_alt
            status = ControlStatus.AVOIDING
            detail = "avoiding an obstacle"
            self._kappa = k_alt
            v = approach(self._v, v_alt, cfg.max_accel_mps2 * self.dt_s)
            w = v * self._kappa
        self._blocked_since = None
        if self.people is not None:
            review = self.people.review(self, cyc.pose, cyc.now_s, v, v_target, self._kappa,
                                        aim.point, kmax, cyc.dist_goal)
            if review is not None and review.arrived and self.goal is not None:
                self._xy_reached = True
                return self._final_heading(cyc, self.goal)
            if review is not None:
                v, self._kappa, status, detail = (review.linear_mps, review.kappa,
                                                  review.status, review.detail)
                w = v * self._kappa
                if review.hold_progress:
                    self.progress.reset()
        return self._finish(cyc, v, w, status, detail)

    def _people_hold_turn(self, cyc: _Cycle, turn_rad: float) -> ControlOutput | None:
        """Someone stands where the corners would swing turning ``turn_rad`` (rad): brake
        and wait (None: turn)."""
        review = None if self.people is None else self.people.review_turn(cyc.pose, cyc.now_s,
                                                                          turn_rad)
        return None if review is None else self._hold(cyc, review)

    def _wait_for_people(self, cyc: _Cycle, detail: str) -> ControlOutput:
        """Brake and wait: a manoeuvre of the controller's own would drive at someone."""
        assert self.people is not None
        return self._hold(cyc, self.people.wait_for_people(cyc.now_s, detail))

    def _hold(self, cyc: _Cycle, review: Review) -> ControlOutput:
        """Brake (turning and driving) and report the people stage's ``review``."""
        step = 2.0 * self.cfg.max_angular_accel_radps2 * self.dt_s
        self._w = approach(self._w, 0.0, step)
        self._v = approach(self._v, 0.0, 2.0 * self.cfg.max_accel_mps2 * self.dt_s)
        if review.hold_progress:
            self.progress.reset()
        traj = rollout(cyc.pose, self._v, self._w, self.cfg.collision_horizon_s, 0.1)
        return ControlOutput(self._v, self._w, review.status, traj, cyc.dist_goal,
                             cyc.remaining, review.detail)

    def _rotation_blocked(self, pose: Pose2D, err: float) -> bool:
        """Whether turning in place towards ``err`` would sweep a corner into an obstacle."""
        if self.costmap is None:
            return False
        traj = rollout(pose, 0.0, math.copysign(0.8, err), 0.5, 0.1)
        hit, _ = self._collides(traj)
        return hit

    # Optional: whether the safety stage would let a command ``(v m/s, ω rad/s)`` through now
    # (its stop zone on the latest scan); the make-room manoeuvre drives only such arcs.
    motion_allowed: Callable[[float, float], bool] | None = None

    REVERSE_SPEED_MPS = 0.15
    REVERSE_TIME_S = 1.5
    MAX_REVERSES = 4  # per 0.3 m of progress along the plan

    def _make_room(self, cyc: _Cycle, target: tuple[float, float]) -> ControlOutput | None:
        """Make room to turn where the rover cannot turn in place: drive the admissible arc
        (backwards or forwards, sharp or gentle) that reaches, in the shortest distance, a
        pose where it can turn towards ``target`` (a three-point turn; out of a wedge along a
        wall, where only a gentle arc away from it fits). None if no arc is admissible."""
        if self.costmap is None or self._reverses >= self.MAX_REVERSES:
            return None
        kmax = 1.0 / max(self.cfg.min_turning_radius_m, 0.05)
        kappas = np.concatenate([np.linspace(-kmax, kmax, 9), GENTLE_KAPPAS])
        n = len(kappas)
        speed = self.REVERSE_SPEED_MPS
        speeds = np.repeat([-speed, speed], n)
        ks = np.tile(kappas, 2)
        dt = 0.25  # s: 3.75 cm between poses, finer than a cell
        trajs = np.stack([rollout(cyc.pose, float(v), float(v * k), MAKE_ROOM_M / speed, dt)
                          for v, k in zip(speeds, ks, strict=True)])
        costs = self.trajectory_costs(trajs, coarse=True)
        lethal = costs[:, 1:] >= LETHAL
        # Steps before the first lethal one (the whole arc when none).
        clear_steps = np.where(lethal.any(axis=1), lethal.argmax(axis=1), lethal.shape[1])
        if self.motion_allowed is not None:  # what the safety stage's stop zone would refuse
            refused = [not self.motion_allowed(float(v), float(v * k))
                       for v, k in zip(speeds, ks, strict=True)]
            clear_steps[np.array(refused, dtype=bool)] = 0
        if self.people is not None and clear_steps.any():
            # Never back (or drive on) at someone: an arc ends before its first pose that
            # would; when people alone leave no arc, wait for them.
            near = self.people.first_too_near(trajs, dt, cyc.now_s)
            clear_steps = np.minimum(clear_steps, np.maximum(near - 1, 0))
            if not clear_steps.any():
                return self._wait_for_people(cyc, "waiting for people to pass before making "
                                             "room to turn")
        if not clear_steps.any():
            return None
        # Every few centimetres along each arc: could the rover turn in place there?
        every = 4  # poses (15 cm)
        on_arc = np.zeros(trajs.shape[:2], dtype=bool)
        on_arc[:, ::every] = True
        m_idx, k_idx = np.nonzero(on_arc)
        keep = (k_idx >= every) & (k_idx <= clear_steps[m_idx])
        m_idx, k_idx = m_idx[keep], k_idx[keep]
        samples = trajs[m_idx, k_idx]
        bearing = np.arctan2(target[1] - samples[:, 1], target[0] - samples[:, 0])
        turn = np.sign((bearing - samples[:, 2] + np.pi) % (2 * np.pi) - np.pi) * 0.8
        spin_t = np.arange(0.0, 0.5 + 1e-9, 0.1)
        spins = np.repeat(samples[:, None, :], len(spin_t), axis=1)
        spins[:, :, 2] = samples[:, None, 2] + turn[:, None] * spin_t[None, :]
        free = ~(self.trajectory_costs(spins, coarse=True)[:, 1:] >= LETHAL).any(axis=1)
        dist = np.full(len(ks), np.inf)  # along each arc to its first such pose, m
        np.minimum.at(dist, m_idx[free], k_idx[free] * dt * speed)
        # Backing out (the way it came in) and straight are preferred a little.
        score = dist + 0.1 * (speeds > 0) + 0.05 * np.abs(ks) / kmax
        if np.isfinite(score).any():
            j = int(np.argmin(score))
            drive_s = float(dist[j]) / speed + 0.3
        else:  # no room within reach: back out the way it came, as far as it fits
            j = int(np.argmax(clear_steps[:n]))
            if clear_steps[j] == 0:
                return None
            drive_s = self.REVERSE_TIME_S
        self._room_v = float(speeds[j])
        self._room_kappa = float(ks[j])
        self._room_until = cyc.now_s + drive_s
        self._reverses += 1
        self._rotating = False
        return self._continue_making_room(cyc)

    def _continue_making_room(self, cyc: _Cycle) -> ControlOutput | None:
        """Go on along the chosen arc (backing out, or forward out of a wedge); None (and
        stop) when it collides."""
        v_target = self._room_v
        traj = rollout(cyc.pose, v_target, v_target * self._room_kappa, 0.6, 0.1)
        hit, _ = self._collides(traj)
        if hit:
            self._room_until = -math.inf
            return None
        if self.people is not None and \
                self.people.first_too_near(traj[None], 0.1, cyc.now_s)[0] < len(traj):
            # Someone came into the way: stop and wait; the manoeuvre is chosen afresh (and
            # not counted against the reversing budget) once they have gone.
            self._room_until = -math.inf
            self._reverses = max(0, self._reverses - 1)
            return self._wait_for_people(cyc, "waiting for people to pass before making "
                                         "room to turn")
        self._kappa = self._room_kappa
        v = approach(self._v, v_target, self.cfg.max_accel_mps2 * self.dt_s)
        w = v * self._kappa
        self._blocked_since = None
        return self._finish(cyc, v, w, ControlStatus.AVOIDING,
                            "backing out to make room to turn" if v_target < 0 else
                            "driving on to make room to turn")

    def _turn(self, err: float) -> tuple[float, float]:
        """In place towards ``err`` (radians): first stop driving, then turn."""
        cfg = self.cfg
        if abs(self._v) > 1e-3:  # brake along the current arc (the radius is kept)
            v = approach(self._v, 0.0, cfg.max_accel_mps2 * self.dt_s)
            return v, v * self._kappa
        w_target = math.copysign(min(cfg.max_angular_radps, max(0.25, 1.5 * abs(err))), err)
        # Decelerate in time: ω ≤ sqrt(2 α |err|).
        w_target = math.copysign(min(abs(w_target),
                                     math.sqrt(2.0 * cfg.max_angular_accel_radps2 * 0.5
                                               * abs(err)) + 0.05), err)
        w = approach(self._w, w_target, cfg.max_angular_accel_radps2 * self.dt_s)
        self._kappa = 0.0
        self._settle_until = -math.inf
        return 0.0, w

    def _sample(self, pose: Pose2D, x_r: float, y_r: float,
                kmax: float) -> tuple[float, float] | None:
        """Best admissible arc ``(v, κ)`` that makes progress, or None."""
        cfg = self.cfg
        target_bearing = math.atan2(y_r, x_r)
        kappas = np.linspace(-kmax, kmax, 11)
        fracs = np.array([1.0, 0.6, 0.3])
        vs = np.repeat(cfg.max_speed_mps * fracs, len(kappas))
        ks = np.tile(kappas, len(fracs))
        trajs = np.stack([rollout(pose, float(v), float(v * k), cfg.collision_horizon_s, 0.1)
                          for v, k in zip(vs, ks, strict=True)])
        if self.costmap is not None:
            costs = self.trajectory_costs(trajs)
            start_hit = costs[:, 0] >= LETHAL
            hit = (costs[:, 1:] >= LETHAL).any(axis=1) & ~start_hit
            worst = costs.max(axis=1).astype(np.float64)
        else:
            hit = np.zeros(len(vs), dtype=bool)
            worst = np.zeros(len(vs))
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        ends = trajs[:, -1, :]
        ex, ey = ends[:, 0] - pose.x, ends[:, 1] - pose.y
        # Progress towards the lookahead point and alignment with it.
        tx, ty = c * x_r - s * y_r, s * x_r + c * y_r
        norm = math.hypot(tx, ty) or 1.0
        progress = (ex * tx + ey * ty) / norm
        align = np.abs((ends[:, 2] - (pose.yaw + target_bearing) + np.pi) % (2 * np.pi) - np.pi)
        score = progress - 0.3 * align - 0.1 * worst / INSCRIBED
        score[hit] = -np.inf
        # Prefer the fastest speed band that has a good option (as the loop used to).
        for band in range(len(fracs)):
            sl = slice(band * len(kappas), (band + 1) * len(kappas))
            j = int(np.argmax(score[sl]))
            if score[sl][j] > 0.05:
                return float(vs[sl][j]), float(ks[sl][j])
        j = int(np.argmax(score))
        if score[j] > 0.0:
            return float(vs[j]), float(ks[j])
        return None

    def _blocked(self, cyc: _Cycle) -> ControlOutput:
        """No admissible motion: brake; BLOCKED once that has lasted ``blocked_timeout_s``."""
        if self._blocked_since is None:
            self._blocked_since = cyc.now_s
        v = approach(self._v, 0.0, 2.0 * self.cfg.max_accel_mps2 * self.dt_s)
        w = v * self._kappa
        self._v, self._w = v, w
        status = (ControlStatus.BLOCKED
                  if cyc.now_s - self._blocked_since >= self.cfg.blocked_timeout_s
                  else ControlStatus.AVOIDING)
        traj = rollout(cyc.pose, v, w, self.cfg.collision_horizon_s, 0.1)
        self.progress.update(cyc.pose, cyc.now_s)
        return ControlOutput(v, w, status, traj, cyc.dist_goal, cyc.remaining,
                             "no admissible motion: the way is blocked")

    def _finish(self, cyc: _Cycle, v: float, w: float, status: ControlStatus,
                detail: str) -> ControlOutput:
        """Command ``(v, w)``: remember it, predict its trajectory, feed the progress
        checker (NO_PROGRESS and zero when it reports the rover stuck)."""
        self._v, self._w = v, w
        traj = rollout(cyc.pose, v, w, self.cfg.collision_horizon_s, 0.1)
        if not self.progress.update(cyc.pose, cyc.now_s):
            return ControlOutput(0.0, 0.0, ControlStatus.NO_PROGRESS, traj, cyc.dist_goal,
                                 cyc.remaining, "no progress")
        return ControlOutput(v, w, status, traj, cyc.dist_goal, cyc.remaining, detail)
