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

import contextlib
import itertools
import logging
import math
from collections.abc import Callable
from typing import Any

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
    NoProgressError,
    StartBlockedError,
    StartOutsideMapError,
)
from curio.nav.controller import ControlStatus, LocalController
from curio.nav.costs import CostGrid
from curio.nav.navigator.ladder import GiveUp, RecoveryLadder
from curio.nav.navigator.pose_gate import PoseGate
from curio.nav.navigator.progress import Progress, ProgressMonitor
from curio.nav.navigator.replanner import KeepOutSpots, Planner, Replanner
from curio.nav.planner import path_length_m
from curio.nav.recovery import Recovery
from curio.nav.validation import GoalValidator

__all__ = ["InvalidGoalError", "NavigatorNode"]

log = logging.getLogger("curio.nav.navigator")

U8 = npt.NDArray[np.uint8]


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

    def __init__(self, cfg: Config, clock: Clock, bus: Bus, costmap: CostGrid,
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
        self.replanner = Replanner(cfg.nav.planner, clock, costmap, planner, controller,
                                   KeepOutSpots(cfg.nav.recovery, costmap))
        self.ladder = RecoveryLadder(cfg.nav.recovery, recovery)
        self._progress_anchor: Pose2D | None = None
        self.pose_gate = PoseGate(cfg.nav.controller.lost_timeout_s)
        self._goal_started_s = 0.0
        self._sent_zero = True
        self.progress = ProgressMonitor(cfg.nav.recovery.goal_progress_timeout_s)
        self.on_done: list[Callable[[GoalHandle], None]] = []

    # --- the action interface -------------------------------------------------------------
    @property
    def plan_count(self) -> int:
        """How many plans were started."""
        return self.replanner.plan_count

    @property
    def keep_out(self) -> list[tuple[float, float, float]]:
        """The live keep-out spots ``(x, y, expiry clock s)`` in ``map``."""
        return self.replanner.keep_out.spots

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
            self.replanner.forget_plan()
            self.bus.publish(PLAN, Path(self.clock.now(), ()))
            self._stop_motion()
        for cb in list(self.on_done):
            cb(handle)

    def _cancel_jobs(self) -> None:
        self.replanner.cancel()
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
    def _with_keep_out(self, costs: U8, start: Pose2D, goal: Pose2D) -> U8:
        """``costs`` with the live keep-out spots made lethal (as the next plan sees them)."""
        return self.replanner.keep_out.apply(costs, start, goal, self.clock.now())

    def _add_keep_out(self, pose: Pose2D) -> None:
        """Remember the spot just ahead on the plan as one to route around."""
        spot = self.replanner.keep_out.add(self.controller, pose, self.clock.now())
        if spot is not None:
            self._event("nav.keep_out", self._active, x=round(spot[0], 3), y=round(spot[1], 3))

    def _plan_step(self, handle: GoalHandle, pose: Pose2D, now: float) -> bool:
        """Follow a finished plan, start the next one when due; whether there is a plan to
        drive on (False: the cycle ends here)."""
        result = self.replanner.take_result(handle)
        if isinstance(result, NavError):
            self._on_plan_error(handle, result)
            return False
        if result is not None:
            self._follow(handle, result)
        have_plan = self.replanner.has_plan(handle.current_index)
        reason = self.replanner.due(pose, now, have_plan)
        if reason == Replanner.PATH_BLOCKED:
            self._event("nav.path_blocked", handle)
        if reason is not None:
            self.replanner.start(pose, handle, reason)
        if not have_plan:
            self._stop_motion()
        return have_plan

    def _follow(self, handle: GoalHandle, poses: list[Pose2D]) -> None:
        """Hand a new plan to the controller (and the progress monitor), publish it."""
        goal = handle.poses[handle.current_index]
        if poses and poses[-1].distance_to(goal) > 0.01:
            # The planner moved a goal too close to an obstacle to the nearest free cell
            # (nav.planner.goal_nearest_free): drive there, with the requested heading.
            goal = Pose2D(poses[-1].x, poses[-1].y, goal.yaw)
        self.progress.on_plan(path_length_m(poses), self.clock.now())
        self.controller.set_plan(poses, goal, check_yaw=math.isfinite(goal.yaw))
        self.bus.publish(PLAN, Path(self.clock.now(), tuple(poses)))

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
        self.replanner.reset()
        self.progress.reset()
        self.pose_gate.reset()
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
            self.replanner.abandon()
            # Motion made by the recovery itself is not progress towards the goal.
            self.progress.pause(self.clock.now())
            if pose is not None:
                self.replanner.start(pose, handle, "after recovery")
            return
        pose = self._usable_pose(handle, pose_msg, now)
        if pose is None:
            return
        if not self._plan_step(handle, pose, now):
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
                f"{self.cfg.nav.recovery.goal_progress_timeout_s:g} s"))
            return
        if out.status in (ControlStatus.BLOCKED, ControlStatus.NO_PROGRESS):
            if out.status is ControlStatus.BLOCKED:
                self._add_keep_out(pose)
            err2: NavError = (ControllerFailedError(
                "the way ahead is blocked and the local controller finds no admissible motion")
                if out.status is ControlStatus.BLOCKED else NoProgressError(
                f"no progress for {self.cfg.nav.controller.progress_timeout_s:g} s"))
            self._stuck(handle, err2)
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
            self.replanner.forget_plan()
            self.controller.clear_plan()
            return
        handle.distance_remaining_m = 0.0
        handle.eta_s = 0.0
        self._finish(handle, GoalState.SUCCEEDED, None, "goal reached")

    def _on_plan_error(self, handle: GoalHandle, err: NavError) -> None:
        if isinstance(err, (GoalOutsideMapError, StartOutsideMapError)):
            self._finish(handle, GoalState.ABORTED, err, "cannot plan")
            return
        if isinstance(err, StartBlockedError):
            # Marks under the rover: clear them at once and try again before the ladder.
            self.ladder.clear_under_rover()
        self._stuck(handle, err)

    def _stuck(self, handle: GoalHandle, err: NavError) -> None:
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
