"""The navigator: goals with action semantics, driving the planner, controller and recovery.

It implements :class:`curio.nav.api.Navigator`. :meth:`NavigatorNode.send_goal` returns a
:class:`~curio.nav.api.GoalHandle` at once; the handle moves PENDING → ACTIVE → SUCCEEDED |
ABORTED (typed ``error``) | PREEMPTED, or straight to REJECTED (a goal outside the map, in an
obstacle, not a number). A sequence of poses is driven waypoint by waypoint. Feedback on the
handle: ``distance_remaining_m`` (along the plan, plus the legs still to come) and ``eta_s``.

Each cycle (``nav.controller.rate_hz``) it reads the pose (``/pose``, ``map``), asks the local
controller for a command and publishes it on ``/cmd_vel_nav`` and the predicted trajectory on
``/local_plan``. Plans come from the global planner off the loop (``Clock.offload``), so the loop
never blocks: at ``nav.planner.replan_rate_hz``, and at once when the current plan
runs into a lethal or inscribed cell of the costmap (an obstacle that was not on the map). When
the rover is stuck (controller blocked, no progress, no path) it climbs the recovery ladder
(``nav.recovery``) and then aborts with the reason. The operator's ``goto`` and ``cancel``
commands (``/operator``) act on it; an engaged e-stop cancels the active goal.

Events (``/events``): ``nav.goal_accepted``, ``nav.goal_rejected``, ``nav.waypoint_reached``,
``nav.goal_succeeded``, ``nav.goal_aborted``, ``nav.goal_preempted``, ``nav.goal_canceled``,
``nav.path_blocked``, ``nav.recovery`` (from the recovery actions).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event, Path, PoseWithCovariance, Twist
from curio.core.topics import (
    CMD_VEL_NAV,
    ESTOP,
    EVENTS,
    LOCAL_PLAN,
    LOCALIZATION,
    OPERATOR,
    PLAN,
    POSE,
)
from curio.nav.api import (
    ControllerFailedError,
    GoalHandle,
    GoalOutsideMapError,
    GoalState,
    InvalidGoalError,
    NavError,
    NoPathError,
    NoProgressError,
    StartBlockedError,
    StartOutsideMapError,
)
from curio.nav.controller import ControlStatus, LocalController
from curio.nav.costs import INSCRIBED, LETHAL, NO_INFORMATION
from curio.nav.navigator.ladder import GiveUp, RecoveryLadder
from curio.nav.navigator.pose_gate import PoseGate
from curio.nav.navigator.progress import Progress, ProgressMonitor
from curio.nav.recovery import Recovery
from curio.nav.validation import GoalValidator

__all__ = ["InvalidGoalError", "NavigatorNode"]

log = logging.getLogger("curio.nav.navigator")

U8 = npt.NDArray[np.uint8]


class PlanCostmap(Protocol):
    """What the navigator needs from the costmap."""

    resolution_m: float
    origin: Pose2D

    def costs(self) -> U8:
        """Immutable snapshot of the cost grid."""
        ...

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        ...

    def world_to_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """(row, col) of a point."""
        ...

    def in_bounds(self, row: int, col: int) -> bool:
        """Whether a cell is on the grid."""
        ...


class Planner(Protocol):
    """What the navigator needs from the global planner."""

    def plan(self, start: Pose2D, goal: Pose2D, costs: U8, resolution_m: float,
             origin: Pose2D) -> list[Pose2D]:
        """A path from start to goal, or a typed NavError."""
        ...


@dataclass
class _PlanJob:
    task: asyncio.Future[list[Pose2D]]
    goal_id: int
    index: int
    reason: str


class NavigatorNode:
    """Goals, planning, control and recovery (see the module docstring).

    Args:
        cfg: the application config.
        clock, bus: injected.
        costmap: the global costmap (snapshots for planning, blocked-path checks).
        planner: the global planner (runs in a worker thread).
        controller: the local controller.
        recovery: the recovery actions; None aborts at once when stuck.
    """

    def __init__(self, cfg: Config, clock: Clock, bus: Bus, costmap: PlanCostmap,
                 planner: Planner, controller: LocalController,
                 recovery: Recovery | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = bus
        self.costmap = costmap
        self.planner = planner
        self.controller = controller
        self.recovery = recovery
        self.validator = GoalValidator(cfg.nav.planner)
        self._ids = itertools.count(1)
        self._active: GoalHandle | None = None
        self._pending: GoalHandle | None = None
        self._plan_job: _PlanJob | None = None
        self._plan: list[Pose2D] = []
        self._plan_goal_index = -1
        self._last_plan_t = -math.inf
        self._blocked_seen_t: float | None = None  # when the current plan was first seen blocked
        self.ladder = RecoveryLadder(cfg.nav.recovery, recovery)
        self._progress_anchor: Pose2D | None = None
        self.pose_gate = PoseGate(cfg.nav.controller.lost_timeout_s)
        self._goal_started_s = 0.0
        self._sent_zero = True
        self.plan_count = 0
        self.progress = ProgressMonitor(cfg.nav.recovery.goal_progress_timeout_s)
        self.keep_out: list[tuple[float, float, float]] = []  # (x, y, expiry clock s)
        self.on_done: list[Callable[[GoalHandle], None]] = []

    # --- the action interface -------------------------------------------------------------
    @property
    def active(self) -> GoalHandle | None:
        """The goal being executed (or about to be), if any; finished goals are not active."""
        for h in (self._pending, self._active):
            if h is not None and not h.done:
                return h
        return None

    def send_goal(self, poses: Pose2D | list[Pose2D], *, tag: str = "") -> GoalHandle:
        """Accept a goal or a waypoint sequence (``map``) and return its handle at once.

        A goal with a NaN yaw has no heading requirement. A previous goal is PREEMPTED. An
        unusable goal comes back REJECTED with ``error`` set (the rover keeps what it was
        doing).
        """
        seq = [poses] if isinstance(poses, Pose2D) else list(poses)
        handle = GoalHandle(next(self._ids), seq, tag=tag)
        try:
            self.validator.check_goals(seq, self.costmap.costs(), self.costmap.resolution_m,
                                       self.costmap.origin)
        except NavError as exc:
            handle.state = GoalState.REJECTED
            handle.error = exc
            handle.history.append(f"rejected: {exc}")
            self._event("nav.goal_rejected", handle, code=exc.code, message=str(exc))
            return handle
        for old in (self._pending, self._active):
            if old is not None and not old.done:
                self._finish(old, GoalState.PREEMPTED, None,
                             f"preempted by goal {handle.goal_id}")
        self._pending = handle
        self._active = None
        handle.history.append("pending")
        return handle

    def cancel(self, reason: str = "canceled") -> None:
        """Cancel the active goal (PREEMPTED) and stop the rover."""
        for h in (self._pending, self._active):
            if h is not None and not h.done:
                self._finish(h, GoalState.PREEMPTED, None, reason, kind="nav.goal_canceled")
        self._pending = None
        self._active = None
        self._stop_motion()

    # --- events and state -------------------------------------------------------------------
    def _event(self, kind: str, handle: GoalHandle | None = None, **detail: Any) -> None:
        d: dict[str, Any] = dict(detail)
        if handle is not None:
            d.setdefault("goal_id", handle.goal_id)
            if handle.tag:
                d.setdefault("tag", handle.tag)
            d.setdefault("goal", [[round(p.x, 3), round(p.y, 3)] for p in handle.poses])
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, d))

    def _finish(self, handle: GoalHandle, state: GoalState, error: NavError | None,
                note: str, kind: str | None = None) -> None:
        handle.state = state
        handle.error = error
        handle.history.append(f"{state.value}: {note}")
        kinds = {GoalState.SUCCEEDED: "nav.goal_succeeded", GoalState.ABORTED: "nav.goal_aborted",
                 GoalState.PREEMPTED: "nav.goal_preempted", GoalState.REJECTED: "nav.goal_rejected"}
        detail: dict[str, Any] = {"note": note,
                                  "time_s": round(self.clock.now() - self._goal_started_s, 3)}
        if error is not None:
            detail["code"] = error.code
            detail["message"] = str(error)
        self._event(kind or kinds[state], handle, **detail)
        if handle is self._active:
            self._cancel_jobs()
            self.controller.clear_plan()
            self._plan = []
            self.bus.publish(PLAN, Path(self.clock.now(), ()))
            self._stop_motion()
        for cb in list(self.on_done):
            cb(handle)

    def _cancel_jobs(self) -> None:
        if self._plan_job is not None:
            self._plan_job.task.cancel()
            self._plan_job = None
        self.ladder.cancel()

    def _hold(self, now: float) -> None:
        """Stand still with the goal kept active (no pose, or localisation lost): the time
        held counts neither against the progress checkers nor as a stuck rover."""
        self._stop_motion()
        self.progress.pause(now)
        self.controller.reset()

    def _usable_pose(self, handle: GoalHandle, msg: PoseWithCovariance | None,
                     now: float) -> Pose2D | None:
        """The pose to drive on, from the pose gate; None: hold still (the goal is aborted
        once that has lasted ``nav.controller.lost_timeout_s``)."""
        verdict = self.pose_gate.check(msg, self.bus.latest(LOCALIZATION), now)
        if verdict.pose is not None:
            return verdict.pose
        if verdict.newly_lost:
            self._event("nav.holding", handle, reason="localisation lost")
        self._hold(now)
        if verdict.error is not None:
            self._finish(handle, GoalState.ABORTED, verdict.error, verdict.reason)
        return None

    def _stop_motion(self) -> None:
        self.bus.publish(CMD_VEL_NAV, Twist(self.clock.now(), 0.0, 0.0, source="navigator"))
        self._sent_zero = True

    # --- planning ---------------------------------------------------------------------------
    def _start_plan(self, start: Pose2D, handle: GoalHandle, reason: str) -> None:
        goal = handle.poses[handle.current_index]
        if not math.isfinite(goal.yaw):
            # No heading wanted: the planner still needs a number for the last pose.
            goal = Pose2D(goal.x, goal.y, math.atan2(goal.y - start.y, goal.x - start.x))
        plain = self.costmap.costs()
        costs = self._with_keep_out(plain, start, goal)
        res = self.costmap.resolution_m
        origin = self.costmap.origin
        planner = self.planner

        def plan() -> list[Pose2D]:
            try:
                return planner.plan(start, goal, costs, res, origin)
            except NoPathError:
                if costs is plain:
                    raise
                # Keep-out spots are a hint to look for another way, never a reason to give
                # up: where they cut the goal off (the only door out), plan without them.
                return planner.plan(start, goal, plain, res, origin)

        task = self.clock.offload(plan)
        self.plan_count += 1
        self._plan_job = _PlanJob(task, handle.goal_id, handle.current_index, reason)
        self._last_plan_t = self.clock.now()

    def _with_keep_out(self, costs: U8, start: Pose2D, goal: Pose2D) -> U8:
        """The costs with the live keep-out spots (where the rover got stuck) made lethal, so a
        replan looks for another way; spots near the start or the goal are left out."""
        now = self.clock.now()
        self.keep_out = [k for k in self.keep_out if k[2] > now]
        radius = self.cfg.nav.recovery.keep_out_radius_m
        spots = [(x, y) for x, y, _ in self.keep_out
                 if math.hypot(x - start.x, y - start.y) > radius + 0.4
                 and math.hypot(x - goal.x, y - goal.y) > radius + 0.2]
        if not spots or radius <= 0.0:
            return costs
        out = costs.copy()
        res = self.costmap.resolution_m
        n = math.ceil(radius / res)
        h, w = out.shape
        for x, y in spots:
            r, c = self.costmap.world_to_cell(x, y)
            rr, cc = np.mgrid[max(0, r - n):min(h, r + n + 1), max(0, c - n):min(w, c + n + 1)]
            inside = (rr - r) ** 2 + (cc - c) ** 2 <= n * n
            out[rr[inside], cc[inside]] = LETHAL
        return out

    def _add_keep_out(self, pose: Pose2D, ahead_m: float = 0.5) -> None:
        """Remember the spot about ``ahead_m`` along the plan as one to route around."""
        plan = self.controller.plan
        if len(plan) == 0 or self.cfg.nav.recovery.keep_out_radius_m <= 0.0:
            return
        i = self.controller.plan_index
        d = np.hypot(plan[i:, 0] - pose.x, plan[i:, 1] - pose.y)
        beyond = np.nonzero(d >= ahead_m)[0]
        j = i + int(beyond[0]) if len(beyond) else len(plan) - 1
        x, y = float(plan[j, 0]), float(plan[j, 1])
        self.keep_out.append((x, y, self.clock.now() + self.cfg.nav.recovery.keep_out_s))
        self._event("nav.keep_out", self._active, x=round(x, 3), y=round(y, 3))

    def _plan_blocked_confirmed(self, pose: Pose2D, now: float) -> bool:
        """Whether the plan has been blocked for ``nav.planner.blocked_confirm_s`` without a
        break.

        Lidar noise next to walls marks and clears single cells from scan to scan; in a narrow
        passage such a flicker would swap the plan for a detour and back every second. A
        blockage counts once it has lasted ``nav.planner.blocked_confirm_s`` (the controller
        and the safety stage guard the rover meanwhile).
        """
        if not self._plan_blocked(pose):
            self._blocked_seen_t = None
            return False
        if self._blocked_seen_t is None:
            self._blocked_seen_t = now
        return now - self._blocked_seen_t >= self.cfg.nav.planner.blocked_confirm_s

    def _plan_blocked(self, pose: Pose2D) -> bool:
        """Whether the plan ahead (about 3 m) crosses a lethal or inscribed cell."""
        if len(self.controller.plan) == 0:
            return False
        plan = self.controller.plan
        i0 = self.controller.plan_index
        ahead = plan[i0:i0 + 60]
        costs = self.costmap.costs()
        rows = np.empty(len(ahead), dtype=np.int64)
        cols = np.empty(len(ahead), dtype=np.int64)
        for k, (x, y, _) in enumerate(ahead):
            rows[k], cols[k] = self.costmap.world_to_cell(float(x), float(y))
        h, w = costs.shape
        ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        if not ok.all():
            return True
        vals = costs[rows, cols]
        # Ignore the first few poses: the rover itself may sit in an inscribed cell.
        near = np.hypot(ahead[:, 0] - pose.x, ahead[:, 1] - pose.y) < 0.35
        return bool(((vals >= INSCRIBED) & (vals != NO_INFORMATION) & ~near).any())

    def _take_plan_result(self, handle: GoalHandle) -> NavError | None:
        job = self._plan_job
        if job is None or not job.task.done():
            return None
        self._plan_job = None
        if job.goal_id != handle.goal_id or job.index != handle.current_index:
            return None
        try:
            poses = job.task.result()
        except asyncio.CancelledError:
            return None
        except NavError as exc:
            return exc
        goal = handle.poses[handle.current_index]
        if poses and poses[-1].distance_to(goal) > 0.01:
            # The planner moved a goal too close to an obstacle to the nearest free cell
            # (nav.planner.goal_nearest_free): drive there, with the requested heading.
            goal = Pose2D(poses[-1].x, poses[-1].y, goal.yaw)
        length = float(sum(a.distance_to(b) for a, b in itertools.pairwise(poses)))
        self.progress.on_plan(length, self.clock.now())
        self._plan = poses
        self._blocked_seen_t = None
        self._plan_goal_index = handle.current_index
        self.controller.set_plan(poses, goal, check_yaw=math.isfinite(goal.yaw))
        self.bus.publish(PLAN, Path(self.clock.now(), tuple(poses)))
        return None

    # --- the cycle --------------------------------------------------------------------------
    def _activate(self, pose: Pose2D | None) -> None:
        handle = self._pending
        if handle is None:
            return
        self._pending = None
        self._active = handle
        handle.state = GoalState.ACTIVE
        handle.history.append("active")
        self._goal_started_s = self.clock.now()
        self.ladder.reset()
        self._plan = []
        self._plan_goal_index = -1
        self._progress_anchor = pose
        self.progress.reset()
        self.pose_gate.reset()
        self.keep_out = []
        self.controller.clear_plan()
        self.controller.reset()
        self._cancel_jobs()
        self._event("nav.goal_accepted", handle, waypoints=len(handle.poses))

    def step(self) -> None:
        """One navigation cycle (synchronous; planning and recovery run as tasks)."""
        now = self.clock.now()
        pose_msg = self.bus.latest(POSE)
        pose = pose_msg.pose if pose_msg is not None else None
        if self._pending is not None:
            self._activate(pose)
        handle = self._active
        if handle is None or handle.done:
            if not self._sent_zero:
                self._stop_motion()
            return
        # A recovery action owns the wheels while it runs.
        if self.ladder.busy:
            if not self.ladder.collect():
                return
            self.controller.reset()
            self._plan_job = None
            # Motion made by the recovery itself is not progress towards the goal.
            self._progress_anchor = pose
            self.progress.pause(self.clock.now())
            if pose is not None:
                self._start_plan(pose, handle, "after recovery")
            return
        pose = self._usable_pose(handle, pose_msg, now)
        if pose is None:
            return
        # Planning.
        err = self._take_plan_result(handle)
        if err is not None:
            self._on_plan_error(handle, err, pose)
            return
        have_plan = self._plan_goal_index == handle.current_index and len(self._plan) > 0
        replan_hz = self.cfg.nav.planner.replan_rate_hz
        if self._plan_job is None:
            if not have_plan:
                self._start_plan(pose, handle, "new goal")
            elif self._plan_blocked_confirmed(pose, now):
                self._event("nav.path_blocked", handle)
                self._start_plan(pose, handle, "path blocked")
            elif replan_hz > 0 and now - self._last_plan_t >= 1.0 / replan_hz:
                self._start_plan(pose, handle, "periodic")
        if not have_plan:
            self._stop_motion()
            return
        # Control.
        out = self.controller.compute(pose, now)
        self.bus.publish(LOCAL_PLAN, Path(now, tuple(Pose2D(float(x), float(y), float(t))
                                                     for x, y, t in out.trajectory)))
        later = sum(handle.poses[k].distance_to(handle.poses[k + 1])
                    for k in range(handle.current_index, len(handle.poses) - 1))
        handle.distance_remaining_m = out.distance_remaining_m + later
        handle.eta_s = handle.distance_remaining_m / max(0.05,
                                                         self.cfg.nav.controller.max_speed_mps)
        if out.status is ControlStatus.GOAL_REACHED:
            self._waypoint_reached(handle)
            return
        progress = self.progress.update(out.distance_remaining_m, now)
        if progress is Progress.IMPROVED:
            self.ladder.note_progress(out.distance_remaining_m)
        elif progress is Progress.STALLED:
            self._add_keep_out(pose)
            self._stuck(handle, NoProgressError(
                f"no progress towards the goal for "
                f"{self.cfg.nav.recovery.goal_progress_timeout_s:g} s"), pose)
            return
        if out.status in (ControlStatus.BLOCKED, ControlStatus.NO_PROGRESS):
            if out.status is ControlStatus.BLOCKED:
                self._add_keep_out(pose)
            err2: NavError = (ControllerFailedError(
                "the way ahead is blocked and the local controller finds no admissible motion")
                if out.status is ControlStatus.BLOCKED else NoProgressError(
                f"no progress for {self.cfg.nav.controller.progress_timeout_s:g} s"))
            self._stuck(handle, err2, pose)
            return
        self.bus.publish(CMD_VEL_NAV, Twist(now, out.linear_mps, out.angular_radps,
                                            source="controller"))
        self._sent_zero = False

    def _waypoint_reached(self, handle: GoalHandle) -> None:
        idx = handle.current_index
        if idx + 1 < len(handle.poses):
            self._event("nav.waypoint_reached", handle, index=idx)
            handle.current_index += 1
            self.progress.reset()
            self._plan = []
            self._plan_goal_index = -1
            self.controller.clear_plan()
            if self._plan_job is not None:
                self._plan_job.task.cancel()
                self._plan_job = None
            return
        handle.distance_remaining_m = 0.0
        handle.eta_s = 0.0
        self._finish(handle, GoalState.SUCCEEDED, None, "goal reached")

    def _on_plan_error(self, handle: GoalHandle, err: NavError, pose: Pose2D) -> None:
        if isinstance(err, (GoalOutsideMapError, StartOutsideMapError)):
            self._finish(handle, GoalState.ABORTED, err, "cannot plan")
            return
        if isinstance(err, StartBlockedError):
            # Marks under the rover: clear them at once and try again before the ladder.
            self.ladder.clear_under_rover()
        self._stuck(handle, err, pose)

    def _stuck(self, handle: GoalHandle, err: NavError, pose: Pose2D) -> None:
        """Climb the recovery ladder, or abort when it is exhausted."""
        self._stop_motion()
        climbed = self.ladder.climb(err, self.progress.best_remaining_m)
        if isinstance(climbed, GiveUp):
            self._finish(handle, GoalState.ABORTED, climbed.error, climbed.note)
            return
        handle.recoveries += 1
        handle.history.append(f"recovery {climbed}: {err.code}")

    # --- task -------------------------------------------------------------------------------
    def _on_operator(self, cmd: Any) -> None:
        if cmd.action == "goto":
            if cmd.goal is None:
                self._event("nav.goal_rejected", None, code="invalid_goal",
                            message="goto without a goal pose", source=cmd.source)
                return
            self.send_goal(cmd.goal, tag=f"{cmd.source or 'operator'} goto")
        elif cmd.action == "cancel":
            self.cancel(f"canceled by {cmd.source or 'the operator'}")
        elif cmd.action == "estop" and self.active is not None:
            self.cancel("e-stop")

    async def run(self) -> None:
        """Run the navigation cycle at ``nav.controller.rate_hz`` until cancelled."""
        op = self.bus.subscribe(OPERATOR)
        estop = self.bus.subscribe(ESTOP)
        period = 1.0 / self.cfg.nav.controller.rate_hz
        warm_up = getattr(self.planner, "warm_up", None)
        if callable(warm_up):
            # Compile the planner's kernels before the first goal (off the loop on real time).
            await self.clock.offload(warm_up)
        next_t = self.clock.now()
        try:
            while True:
                for cmd in op.drain():
                    self._on_operator(cmd)
                for e in estop.drain():
                    if e.engaged and self.active is not None:
                        self.cancel("e-stop engaged")
                self.step()
                next_t += period
                if next_t < self.clock.now():  # late: skip ahead, never catch up
                    next_t = self.clock.now() + period
                await self.clock.sleep_until(next_t)
        finally:
            op.close()
            estop.close()
            self._cancel_jobs()

    async def close(self) -> None:
        """Cancel background work."""
        self._cancel_jobs()
        with contextlib.suppress(Exception):
            self._stop_motion()
