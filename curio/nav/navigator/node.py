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

The policies are small classes of their own, each unit-tested: :class:`GoalTracker` (the
handles, waypoints, feedback and goal events), :class:`PoseGate` (no pose, a stale pose or
localisation lost: hold, then give up), :class:`Replanner` (when to plan; keep-out spots),
:class:`ProgressMonitor` (closer to the goal along the plan, or stalled) and
:class:`RecoveryLadder` (rungs, rounds, the running action). :meth:`NavigatorNode.step` is
the cycle that ties them together.

Events (``/events``): ``nav.goal_accepted``, ``nav.goal_rejected``, ``nav.waypoint_reached``,
``nav.goal_succeeded``, ``nav.goal_aborted``, ``nav.goal_preempted``, ``nav.goal_canceled``,
``nav.holding``, ``nav.path_blocked``, ``nav.keep_out``, ``nav.recovery`` (from the recovery
actions).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorCommand, Path, PoseWithCovariance, Twist
from curio.core.topics import CMD_VEL_NAV, ESTOP, LOCAL_PLAN, LOCALIZATION, OPERATOR, PLAN, POSE
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
from curio.nav.controller import ControlOutput, ControlStatus, LocalController
from curio.nav.costs import CostGrid
from curio.nav.navigator.goals import GoalTracker
from curio.nav.navigator.ladder import GiveUp, RecoveryActions, RecoveryLadder
from curio.nav.navigator.pose_gate import PoseGate
from curio.nav.navigator.progress import Progress, ProgressMonitor
from curio.nav.navigator.replanner import KeepOutSpots, Planner, Replanner
from curio.nav.planner import path_length_m
from curio.nav.validation import GoalValidator

__all__ = ["InvalidGoalError", "NavigatorNode"]

U8 = npt.NDArray[np.uint8]


class NavigatorNode:
    """Goals, planning, control and recovery (see the module docstring).

    Args:
        cfg: the application config.
        clock, bus: injected.
        costmap: the global costmap (snapshots for planning, blocked-path checks).
        planner: the global planner (runs in a worker thread).
        controller: the local controller.
        recovery: the recovery actions (:class:`~curio.nav.recovery.Recovery`); None aborts at
            once when stuck.
    """

    def __init__(self, cfg: Config, clock: Clock, bus: Bus, costmap: CostGrid,
                 planner: Planner, controller: LocalController,
                 recovery: RecoveryActions | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = bus
        self.costmap = costmap
        self.planner = planner
        self.controller = controller
        self.validator = GoalValidator(cfg.nav.planner)
        self.goals = GoalTracker(clock, bus)
        self.pose_gate = PoseGate(cfg.nav.controller.lost_timeout_s)
        self.replanner = Replanner(cfg.nav.planner, clock, costmap, planner, controller,
                                   KeepOutSpots(cfg.nav.recovery, costmap))
        self.progress = ProgressMonitor(cfg.nav.recovery.goal_progress_timeout_s)
        self.ladder = RecoveryLadder(cfg.nav.recovery, recovery)
        self._sent_zero = True
        self.on_done: list[Callable[[GoalHandle], None]] = []
        # Reasons to stand still with the goal kept active (another rover has the right of
        # way, curio/fleet/traffic.py): each returns why, or None; asked every cycle.
        self.holds: list[Callable[[Pose2D, float], str | None]] = []
        self.held_by: str | None = None

    # --- the action interface -------------------------------------------------------------
    @property
    def active(self) -> GoalHandle | None:
        """The goal being executed (or about to be), if any; finished goals are not active."""
        return self.goals.active

    @property
    def plan_count(self) -> int:
        """How many plans were started."""
        return self.replanner.plan_count

    @property
    def keep_out(self) -> list[tuple[float, float, float]]:
        """The live keep-out spots ``(x, y, expiry clock s)`` in ``map``."""
        return self.replanner.keep_out.spots

    def send_goal(self, poses: Pose2D | list[Pose2D], *, tag: str = "") -> GoalHandle:
        """Accept a goal or a waypoint sequence (``map``) and return its handle at once.

        A goal with a NaN yaw has no heading requirement. A previous goal is PREEMPTED. An
        unusable goal comes back REJECTED with ``error`` set (the rover keeps what it was
        doing).
        """
        seq = [poses] if isinstance(poses, Pose2D) else list(poses)
        handle = self.goals.new(seq, tag)
        try:
            self.validator.check_goals(seq, self.costmap.costs(), self.costmap.resolution_m,
                                       self.costmap.origin)
        except NavError as exc:
            self.goals.reject(handle, exc)
            return handle
        for old in (self.goals.pending, self.goals.current):
            if old is not None and not old.done:
                self._finish(old, GoalState.PREEMPTED, None,
                             f"preempted by goal {handle.goal_id}")
        self.goals.queue(handle)
        return handle

    def cancel(self, reason: str = "canceled") -> None:
        """Cancel the active goal (PREEMPTED) and stop the rover."""
        for h in (self.goals.pending, self.goals.current):
            if h is not None and not h.done:
                self._finish(h, GoalState.PREEMPTED, None, reason, kind="nav.goal_canceled")
        self.goals.clear()
        self._stop_motion()

    # --- the cycle --------------------------------------------------------------------------
    def step(self) -> None:
        """One navigation cycle (synchronous; planning and recovery run as tasks): activate a
        new goal; wait while a recovery action owns the wheels; pass the pose gate; plan;
        control."""
        now = self.clock.now()
        pose_msg = self.bus.latest(POSE)
        if self.goals.pending is not None:
            self._activate()
        handle = self.goals.current
        if handle is None or handle.done:
            self.held_by = None
            if not self._sent_zero:
                self._stop_motion()
            return
        if self.ladder.busy:
            if self.ladder.collect():
                self._after_recovery(handle, pose_msg)
            return
        pose = self._usable_pose(handle, pose_msg, now)
        if pose is not None and self._plan_step(handle, pose, now) \
                and not self._held(handle, pose, now):
            self._control(handle, pose, now)

    def _activate(self) -> None:
        """The pending goal becomes the current one; every policy starts afresh."""
        handle = self.goals.activate()
        if handle is None:
            return
        self.ladder.reset()
        self.replanner.reset()
        self.progress.reset()
        self.pose_gate.reset()
        self.controller.clear_plan()
        self.controller.reset()
        self._cancel_jobs()
        self.goals.event("nav.goal_accepted", handle, waypoints=len(handle.poses))

    def _after_recovery(self, handle: GoalHandle, msg: PoseWithCovariance | None) -> None:
        """A recovery action has ended: plan afresh from where it left the rover."""
        self.controller.reset()
        self.replanner.abandon()
        # Motion made by the recovery itself is not progress towards the goal.
        self.progress.pause(self.clock.now())
        if msg is not None:
            self.replanner.start(msg.pose, handle, "after recovery")

    def _usable_pose(self, handle: GoalHandle, msg: PoseWithCovariance | None,
                     now: float) -> Pose2D | None:
        """The pose to drive on, from the pose gate; None: hold still (the goal is aborted
        once that has lasted ``nav.controller.lost_timeout_s``)."""
        verdict = self.pose_gate.check(msg, self.bus.latest(LOCALIZATION), now)
        if verdict.pose is not None:
            return verdict.pose
        if verdict.newly_lost:
            self.goals.event("nav.holding", handle, reason="localisation lost")
        self._hold(now)
        if verdict.error is not None:
            self._finish(handle, GoalState.ABORTED, verdict.error, verdict.reason)
        return None

    def _held(self, handle: GoalHandle, pose: Pose2D, now: float) -> bool:
        """Stand still while one of :attr:`holds` gives a reason (``nav.holding`` once)."""
        reason = next((r for r in (hold(pose, now) for hold in self.holds) if r), None)
        if reason != self.held_by:
            if reason:
                self.goals.event("nav.holding", handle, reason=reason)
            self.held_by = reason
        if reason:
            self._hold(now)
        return reason is not None

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
            self.goals.event("nav.path_blocked", handle)
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

    def _control(self, handle: GoalHandle, pose: Pose2D, now: float) -> None:
        """Ask the controller for a command; judge progress; drive, or climb the ladder."""
        out = self.controller.compute(pose, now)
        self.bus.publish(LOCAL_PLAN, Path(now, tuple(Pose2D(float(x), float(y), float(t))
                                                     for x, y, t in out.trajectory)))
        self.goals.feedback(handle, out.distance_remaining_m,
                            self.cfg.nav.controller.max_speed_mps)
        if out.status is ControlStatus.GOAL_REACHED:
            self._waypoint_reached(handle)
            return
        if out.status is ControlStatus.YIELDING:
            self.progress.pause(now)  # waiting for people to pass is not being stuck
        progress = self.progress.update(out.distance_remaining_m, now)
        if progress is Progress.IMPROVED:
            self.ladder.note_progress(out.distance_remaining_m)
        elif progress is Progress.STALLED:
            self._add_keep_out(pose)
            self._stuck(handle, NoProgressError(
                f"no progress towards the goal for {self.progress.timeout_s:g} s"))
            return
        if out.status in (ControlStatus.BLOCKED, ControlStatus.NO_PROGRESS):
            if out.status is ControlStatus.BLOCKED:
                self._add_keep_out(pose)
            self._stuck(handle, self._controller_error(out))
            return
        self.bus.publish(CMD_VEL_NAV, Twist(now, out.linear_mps, out.angular_radps,
                                            source="controller"))
        self._sent_zero = False

    def _controller_error(self, out: ControlOutput) -> NavError:
        """The typed failure for a controller that is BLOCKED or makes NO_PROGRESS."""
        if out.status is ControlStatus.BLOCKED:
            return ControllerFailedError(
                "the way ahead is blocked and the local controller finds no admissible motion")
        return NoProgressError(
            f"no progress for {self.cfg.nav.controller.progress_timeout_s:g} s")

    def _waypoint_reached(self, handle: GoalHandle) -> None:
        if self.goals.advance(handle):
            self.progress.reset()
            self.replanner.forget_plan()
            self.controller.clear_plan()
            return
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

    # --- keep-out spots ---------------------------------------------------------------------
    def _with_keep_out(self, costs: U8, start: Pose2D, goal: Pose2D) -> U8:
        """``costs`` with the live keep-out spots made lethal (as the next plan sees them)."""
        return self.replanner.keep_out.apply(costs, start, goal, self.clock.now())

    def _add_keep_out(self, pose: Pose2D) -> None:
        """Remember the spot just ahead on the plan as one to route around."""
        spot = self.replanner.keep_out.add(self.controller, pose, self.clock.now())
        if spot is not None:
            self.goals.event("nav.keep_out", self.goals.current, x=round(spot[0], 3),
                             y=round(spot[1], 3))

    # --- ending goals and motion ------------------------------------------------------------
    def _finish(self, handle: GoalHandle, state: GoalState, error: NavError | None,
                note: str, kind: str | None = None) -> None:
        """End a goal; when it is the current one, stop planning, recovery and the rover."""
        self.goals.finish(handle, state, error, note, kind)
        if handle is self.goals.current:
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

    def _stop_motion(self) -> None:
        self.bus.publish(CMD_VEL_NAV, Twist(self.clock.now(), 0.0, 0.0, source="navigator"))
        self._sent_zero = True

    # --- task -------------------------------------------------------------------------------
    def _on_operator(self, cmd: OperatorCommand) -> None:
        if cmd.action == "goto":
            if cmd.goal is None:
                self.goals.event("nav.goal_rejected", None, code="invalid_goal",
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
        try:
            async for _ in self.clock.every(period, immediate=True):
                for cmd in op.drain():
                    self._on_operator(cmd)
                for e in estop.drain():
                    if e.engaged and self.active is not None:
                        self.cancel("e-stop engaged")
                self.step()
        finally:
            op.close()
            estop.close()
            self._cancel_jobs()

    async def close(self) -> None:
        """Cancel background work."""
        self._cancel_jobs()
        with contextlib.suppress(Exception):
            self._stop_motion()
