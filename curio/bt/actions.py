"""Actions: what the branches of the priority selector do, each a small non-blocking machine.

E-stop hold, pause, go home (operator or low battery), change path, ask for help, follow the
route, idle; and for the two-step tree, clear a request and drive to one fixed goal. Actions
start navigator goals through the :class:`~curio.bt.follower.PathFollower` (or the navigator
itself) and poll the goal handles on later ticks.
"""

from __future__ import annotations

from typing import Any

from py_trees.common import Status

from curio.core.geometry import Pose2D
from curio.nav.api import GoalHandle, GoalState

from .context import CurioBehaviour, TreeContext
from .follower import Route
from .paths import HOME_PATH_ID, PathError, format_xy
from .unattended import lost_report

__all__ = [
    "Ask4Help",
    "BatteryHome",
    "ChangePath",
    "ClearKey",
    "DriveHome",
    "FollowPath",
    "HoldEStop",
    "Idle",
    "MoveClient",
    "Pause",
]


class HoldEStop(CurioBehaviour):
    """While the e-stop is engaged: hold the route, cancel any goal, RUNNING.

    When released (the guard fails and this is stopped), a route that was in progress stays
    held under Pause: the rover does not drive off by itself after an e-stop.
    """

    def __init__(self, ctx: TreeContext, name: str = "Hold (e-stop)") -> None:
        super().__init__(name, ctx, write=("paused",))
        self.had_route = False

    def initialise(self) -> None:
        """Stop the route now."""
        f = self.ctx.follower
        self.had_route = f.active or bool(self.get("paused"))
        f.hold("estop")
        self.ctx.cancel_foreign_goal()
        self.ctx.sink.status("E-stop", "estop")

    def update(self) -> Status:
        """Hold; cancel anything the dashboard sends meanwhile."""
        self.ctx.cancel_foreign_goal()
        self.ctx.sink.status("E-stop", "estop")
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        """Released: pause if a route was in progress, else idle."""
        if new_status == Status.INVALID and self.had_route:
            self.set("paused", True)
            self.ctx.sink.status("Paused", "paused")
            self.ctx.sink.event("bt.estop_released",
                                message="E-stop released: the rover is paused; press Resume "
                                        "to continue.")
        self.had_route = False


class Pause(CurioBehaviour):
    """The pause toggle (original §1.5, fixed): RUNNING while paused, holding every branch below.

    Pause keeps the waypoint; Resume re-sends the same waypoint. Resume when not paused retries
    a failed or interrupted waypoint, else says there is nothing to resume. Pausing an idle
    rover is allowed (nothing moves on resume, §9.14). Paused and lost (``lost``: carried
    elsewhere, say), it reports it as the Lost branch would, without the turn
    (:class:`~curio.bt.unattended.LostReport`: the localiser's search, ``localization.lost``,
    a help request after ``relocalise_timeout_s``, ``localization.found``) and stays paused.
    """

    def __init__(self, ctx: TreeContext, name: str = "Pause") -> None:
        super().__init__(name, ctx, read=("lost", "lost_hint"),
                         write=("paused", "pause_request"))
        # Paused and lost (carried elsewhere, say): the Lost branch below is held, so the
        # pause says so and lets the localiser search itself, without moving.
        self.lost = lost_report(ctx, self.get)

    def update(self) -> Status:
        """Apply a pending pause/resume, then FAILURE (not paused) or RUNNING (paused)."""
        ctx = self.ctx
        req = self.get("pause_request")
        if req is not None:
            self.set("pause_request", None)
            if req["action"] == "pause":
                if self.get("paused"):
                    ctx.accept(req, req["action"], "Already paused.")
                else:
                    self.set("paused", True)
                    ctx.follower.hold("pause")
                    ctx.accept(req, "pause", "Paused.")
            elif self.get("paused"):
                self.set("paused", False)
                if ctx.follower.resume():
                    ctx.accept(req, "resume", "Resumed.")
                else:
                    ctx.sink.status("Idle", "idle")
                    ctx.accept(req, "resume", "Resumed; there is no route to continue.")
                return Status.FAILURE
            elif ctx.follower.phase in ("failed", "interrupted") and ctx.follower.resume():
                stop = ctx.follower.current_stop()
                where = stop.label() if stop is not None else "the waypoint"
                ctx.accept(req, "resume", f"Trying {where} again.")
            else:
                ctx.accept(req, "resume", "The rover is not paused.")
        if self.get("paused"):
            if ctx.follower.phase != "held":
                ctx.follower.hold("pause")
            ctx.cancel_foreign_goal()
            if self.get("lost"):
                if not (self.lost.active and self.lost.paused):
                    self.lost.begin(0.0, paused=True)
                self.lost.update()
            else:
                ctx.sink.status("Paused", "paused")
            return Status.RUNNING
        return Status.FAILURE


class DriveHome(CurioBehaviour):
    """One Go Home press: switch to path 0 once (the original sent "0" twice, §9.4); SUCCESS."""

    def __init__(self, ctx: TreeContext, name: str = "Drive Home") -> None:
        super().__init__(name, ctx, write=("home_request",))

    def update(self) -> Status:
        """Consume the request and start the home path (unless already heading home)."""
        ctx = self.ctx
        req = self.take("home_request")
        f = ctx.follower
        if f.route_id == HOME_PATH_ID and f.phase == "moving":
            ctx.accept(req, "go_home", "Already going home.")
            return Status.SUCCESS
        try:
            message = f.switch(ctx.home_route())
        except (PathError, ValueError) as exc:
            ctx.reject(req, "go_home", str(exc))
            return Status.FAILURE
        ctx.accept(req, "go_home", message)
        return Status.SUCCESS


class BatteryHome(CurioBehaviour):
    """Low battery: start the home path once per low episode (hysteresis in Battery2BB); with
    a dock, ask for docking instead (the Dock branch, ``curio/bt/unattended.py``)."""

    def __init__(self, ctx: TreeContext, name: str = "Battery Home") -> None:
        super().__init__(name, ctx, read=("battery_v",),
                         write=("battery_home_pending", "dock_request"))

    def update(self) -> Status:
        """Consume the pending go-home; SUCCESS."""
        self.set("battery_home_pending", False)
        f = self.ctx.follower
        if f.speak is not None:  # say why the tour ends here
            f.speak("My battery is low: I am going to charge it. Sorry!")
        if self.ctx.docker is not None:
            if f.active:
                f.stop(f"Battery low ({self.get('battery_v')} V)")
            if not self.ctx.docker.docked:
                self.set("dock_request", {"reason": "battery", "action": "dock"})
            return Status.SUCCESS
        if not (f.route_id == HOME_PATH_ID and f.phase in ("moving", "finished")):
            f.switch(self.ctx.home_route())
        return Status.SUCCESS


class ChangePath(CurioBehaviour):
    """Apply the pending route command: select a path (equivalent-waypoint rule), cancel, or
    start/stop the tour. SUCCESS when applied; FAILURE (with a rejection) otherwise."""

    def __init__(self, ctx: TreeContext, name: str = "Change Path") -> None:
        super().__init__(name, ctx, write=("command",))

    def update(self) -> Status:
        """Consume ``command``."""
        ctx = self.ctx
        req = self.take("command")
        if req is None:
            return Status.FAILURE
        action = req["action"]
        f = ctx.follower
        try:
            if action == "select_path":
                route = Route.from_path(ctx.paths.get(req["path_id"]))
                ctx.accept(req, action, f.switch(route))
            elif action == "start_tour":
                assert ctx.tour_route is not None
                f.switch(ctx.tour_route)
                n = len(ctx.tour_route)
                ctx.accept(req, action, f"Tour started: {n} stop{'s' if n != 1 else ''}.")
            elif action == "stop_tour":
                f.stop("Tour stopped")
                ctx.accept(req, action, "Tour stopped.")
            elif action == "cancel":
                was = f.active
                f.stop("Idle")
                ctx.accept(req, action, "Stopped." if was else "Nothing to cancel.")
        except (PathError, ValueError) as exc:
            ctx.reject(req, action, str(exc))
            return Status.FAILURE
        return Status.SUCCESS


class Ask4Help(CurioBehaviour):
    """Ask a person to clear the way (original §1.6, fixed): one request, hold, resume.

    * Start: hold the route, event ``help.requested`` (HELP ME), status ``Needs help``.
    * The way stays clear for ``help_clear_s`` → ``help.resolved`` ("Thanks!"), resume, FAILURE
      (Follow Path runs in the same tick). "Clear" is judged by the :class:`WayProbe` (a path
      to the held waypoint exists on the live costmap) when there is one, else by BLOCKED.
    * The operator presses *help done* → the same, and BLOCKED is ignored for ``help_rearm_s``
      unless it reports clear first (so the stale flag of a rover that has not moved yet does
      not ask again at once, §9.25).
    * No help in ``help_timeout_s`` → ``help_timeout_action``: ``replan`` (resume; the planner
      routes around what the costmap now holds), ``go_home``, or ``keep_waiting`` (one
      ``help.timeout`` event, then keep holding).
    * Pre-empted (pause, e-stop, Go Home, a path command): the request is withdrawn
      (``help.resolved`` with reason ``preempted``) and re-armed like help done.
    """

    def __init__(self, ctx: TreeContext, name: str = "Ask4Help") -> None:
        super().__init__(name, ctx,
                         read=("blocked", "obstacle_distance_m"),
                         write=("help_active", "help_done", "help_rearm_until"))
        self.requested_at = 0.0
        self.clear_since: float | None = None
        self.open = False
        self.timeout_reported = False
        self.next_probe_s = 0.0

    def _way_clear(self, now: float) -> bool:
        probe = self.ctx.probe
        stop = self.ctx.follower.current_stop()
        if probe is None or stop is None:
            return not self.get("blocked")
        result = probe.poll()
        if not probe.busy and now >= self.next_probe_s:
            yaw = stop.yaw_rad if stop.yaw_rad is not None else 0.0
            probe.start(Pose2D(stop.x_m, stop.y_m, yaw), now)
            self.next_probe_s = now + max(0.25, self.ctx.cfg.help_clear_s / 4.0)
            result = probe.poll()
        return result is not None and result.clear and result.started_s >= self.requested_at

    def initialise(self) -> None:
        """Hold the route and ask for help (once)."""
        ctx = self.ctx
        f = ctx.follower
        stop = f.current_stop()
        self.requested_at = ctx.clock.now()
        self.clear_since = None
        self.timeout_reported = False
        self.next_probe_s = self.requested_at
        if ctx.probe is not None:
            ctx.probe.reset()
        self.open = True
        self.set("help_active", True)
        self.set("help_done", None)
        trigger = f.last_error_code if f.failed_blocked else "blocked"
        f.hold("help")
        distance = self.get("obstacle_distance_m")
        ctx.sink.event("help.requested", message="HELP ME! Something blocks my way.",
                       trigger=trigger, error=f.last_error if f.failed_blocked else "",
                       path_id=f.route_id, index=f.index,
                       x_m=stop.x_m if stop else None, y_m=stop.y_m if stop else None,
                       obstacle_distance_m=distance)
        ctx.sink.status("Needs help", "needs_help")

    def update(self) -> Status:
        """Wait for the way to clear, the operator, or the timeout."""
        ctx = self.ctx
        now = ctx.clock.now()
        done = self.get("help_done")
        if done is not None:
            self.set("help_done", None)
            ctx.accept(done, "help_done", "Thanks!")
            return self._resolve("help_done", "Thanks!", rearm=True)
        if self._way_clear(now):
            if self.clear_since is None:
                self.clear_since = now
            if now - self.clear_since >= ctx.cfg.help_clear_s:
                return self._resolve("clear", "Thanks!", rearm=False)
        else:
            self.clear_since = None
        if now - self.requested_at >= ctx.cfg.help_timeout_s:
            action = ctx.cfg.help_timeout_action
            waited = f"No help came in {ctx.cfg.help_timeout_s:g} s"
            if action == "replan":
                return self._resolve("timeout", f"{waited}: trying another route.", rearm=True)
            if action == "go_home":
                status = self._resolve("timeout", f"{waited}: going home.", rearm=True,
                                       resume=False)
                ctx.follower.switch(ctx.home_route())
                return status
            if not self.timeout_reported:
                self.timeout_reported = True
                ctx.sink.event("help.timeout", message=f"{waited}; still waiting.",
                               waited_s=round(now - self.requested_at, 3))
        ctx.sink.status("Needs help", "needs_help")
        return Status.RUNNING

    def _resolve(self, reason: str, message: str, *, rearm: bool,
                 resume: bool = True) -> Status:
        ctx = self.ctx
        self.open = False
        self.set("help_active", False)
        if rearm:
            self.set("help_rearm_until", ctx.clock.now() + ctx.cfg.help_rearm_s)
        ctx.sink.event("help.resolved", message=message, reason=reason,
                       waited_s=round(ctx.clock.now() - self.requested_at, 3))
        if resume:
            ctx.follower.resume()
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        """Pre-empted while asking: withdraw the request (the banner must not lie)."""
        if self.open:
            self.open = False
            self.set("help_active", False)
            self.set("help_rearm_until", self.ctx.clock.now() + self.ctx.cfg.help_rearm_s)
            self.ctx.sink.event("help.resolved", message="Help is no longer needed.",
                                reason="preempted",
                                waited_s=round(self.ctx.clock.now() - self.requested_at, 3))


class FollowPath(CurioBehaviour):
    """Drive the current route: RUNNING while moving or dwelling, SUCCESS on the tick the route
    finishes, FAILURE when there is nothing to drive (then Idle runs)."""

    def __init__(self, ctx: TreeContext, name: str = "Follow Path") -> None:
        super().__init__(name, ctx, read=("paused",))

    def update(self) -> Status:
        """Step the follower."""
        f = self.ctx.follower
        if f.phase == "held":  # nothing above holds it any more (e.g. a pre-empted help)
            f.resume()
        before = f.phase
        phase = f.step()
        if phase in ("moving", "dwelling"):
            return Status.RUNNING
        if phase == "finished" and before != "finished":
            return Status.SUCCESS
        return Status.FAILURE


class Idle(CurioBehaviour):
    """Always RUNNING (the selector never fails). Shows ``Idle``, or the progress of a goal the
    dashboard sent directly to the navigator."""

    def __init__(self, ctx: TreeContext, name: str = "Idle") -> None:
        super().__init__(name, ctx)
        self.watched: GoalHandle | None = None

    def update(self) -> Status:
        """Report status."""
        ctx = self.ctx
        sink = ctx.sink
        nav = ctx.navigator
        active = nav.active if nav is not None else None
        if active is not None and not ctx.follower.owns(active):
            self.watched = active
        watched = self.watched
        if watched is not None and watched.poses:
            goal = watched.poses[-1]
            label = format_xy(goal.x, goal.y)
            if not watched.done:
                sink.status(f"Moving to {label}", "moving")
                return Status.RUNNING
            self.watched = None
            if watched.state is GoalState.SUCCEEDED:
                sink.status(f"Arrived at {label}", "arrived")
            elif watched.state in (GoalState.ABORTED, GoalState.REJECTED):
                reason = str(watched.error) if watched.error is not None else "failed"
                sink.status(f"Could not reach {label}: {reason}", "idle")
            else:
                sink.status("Idle", "idle")
            return Status.RUNNING
        if sink.state in ("", "paused", "estop", "needs_help", "moving", "going_home", "tour"):
            sink.status("Idle", "idle")
        return Status.RUNNING


class ClearKey(CurioBehaviour):
    """Set ``key`` to ``value`` and succeed (consumes a request in the two-step tree)."""

    def __init__(self, ctx: TreeContext, key: str, value: Any = None,
                 name: str | None = None) -> None:
        super().__init__(name or f"Clear {key}", ctx, write=(key,))
        self.key = key
        self.value = value

    def update(self) -> Status:
        """Write; SUCCESS."""
        if self.key == "home_request":
            req = self.get(self.key)
            if req is not None:
                self.ctx.accept(req, "go_home", "Going home.")
        self.set(self.key, self.value)
        return Status.SUCCESS


class MoveClient(CurioBehaviour):
    """Drive to one fixed goal (original §1.1, fixed): the goal is sent when the behaviour
    starts (not stamped at setup), status on change only, cancelled when pre-empted, and a
    failed goal is not re-sent for ``retry_s`` (no goal storm)."""

    def __init__(self, ctx: TreeContext, name: str, goal: Pose2D, *, home: bool = False,
                 retry_s: float = 5.0) -> None:
        super().__init__(name, ctx)
        self.goal = goal
        self.home = home
        self.retry_s = retry_s
        self.handle: GoalHandle | None = None
        self.failed_at: float | None = None
        self.label = format_xy(goal.x, goal.y)

    def initialise(self) -> None:
        """Send the goal (unless a recent failure says wait)."""
        ctx = self.ctx
        self.handle = None
        now = ctx.clock.now()
        if self.failed_at is not None and now - self.failed_at < self.retry_s:
            return
        self.failed_at = None
        if ctx.navigator is None:
            return
        self.handle = ctx.navigator.send_goal(self.goal, tag=self.name)

    def update(self) -> Status:
        """Map the goal state to a status."""
        ctx = self.ctx
        handle = self.handle
        if handle is None:
            if self.failed_at is None:
                self.failed_at = ctx.clock.now()
                ctx.sink.status(f"Could not reach {self.label}: navigation is not running",
                                "idle")
            return Status.FAILURE
        if handle.state is GoalState.SUCCEEDED:
            ctx.sink.status(f"Arrived at {self.label}", "arrived")
            ctx.sink.event("waypoint.reached", path_id=None, index=None, name=self.name,
                           x_m=self.goal.x, y_m=self.goal.y)
            return Status.SUCCESS
        if not handle.done:
            if self.home:
                ctx.sink.status("Going home", "going_home")
            else:
                ctx.sink.status(f"Moving to {self.label}", "moving")
            return Status.RUNNING
        self.failed_at = ctx.clock.now()
        reason = str(handle.error) if handle.error is not None else handle.state.value
        ctx.sink.status(f"Could not reach {self.label}: {reason}", "idle")
        ctx.sink.event("waypoint.failed", path_id=None, index=None, name=self.name,
                       x_m=self.goal.x, y_m=self.goal.y,
                       error=getattr(handle.error, "code", handle.state.value),
                       message=reason)
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        """Pre-empted while active: cancel our goal (the original left it running, §9.33)."""
        handle = self.handle
        nav = self.ctx.navigator
        if new_status == Status.INVALID and handle is not None and (
                not handle.done or handle.state is GoalState.PREEMPTED):
            if nav is not None and nav.active is handle:
                nav.cancel()
            self.ctx.sink.event("goal.preempted", name=self.name, x_m=self.goal.x,
                                y_m=self.goal.y, message="Goal was preempted")
        self.handle = None
