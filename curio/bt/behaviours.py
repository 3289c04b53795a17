"""The behaviours of Curio's trees (py_trees 2.x), each a small non-blocking state machine.

Every behaviour reads and writes the blackboard through its own py_trees client with declared
READ/WRITE keys, in the tree's namespace (two trees in one process never share keys). None of
them awaits: actions start navigator goals through the :class:`~curio.bt.follower.PathFollower`
and poll the goal handles on later ticks (py_trees issue #420's advice).

Data feeds (``Operator2BB``, ``Blocked2BB``, ``EStop2BB``, ``Battery2BB``) always return
SUCCESS in one tick: unlike the original's ToBlackboard (RUNNING until a message arrives,
§1.0, §9.2–9.3), no feed can stall another, a missing publisher leaves a safe default
("not blocked", "no e-stop", "battery unknown"), and operator commands arrive through a
reliable queue, each one answered by ``bt.command_accepted`` or ``bt.command_rejected`` with a
sentence for the operator.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import Access, Status

from curio.core.bus import Bus, Subscription
from curio.core.clock import Clock
from curio.core.config import BtConfig
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorCommand
from curio.core.topics import BATTERY, BLOCKED, ESTOP, OPERATOR
from curio.nav.api import GoalHandle, GoalState

from .follower import TOUR_ROUTE_ID, PathFollower, Route, StatusSink
from .paths import HOME_PATH_ID, PathError, PathManager, format_xy
from .probe import WayProbe

__all__ = [
    "BB_DEFAULTS",
    "Ask4Help",
    "Battery2BB",
    "BatteryHome",
    "Blocked2BB",
    "ChangePath",
    "ClearKey",
    "DriveHome",
    "EStop2BB",
    "FollowPath",
    "HoldEStop",
    "Idle",
    "IsBlocked",
    "MoveClient",
    "Operator2BB",
    "Pause",
    "TreeContext",
]

log = logging.getLogger("curio.bt")

# Every blackboard key with its initial value (original-system.md §2.3, fixed: ``blocked``
# replaces the inverted ``pathclear`` and starts False, §9.1–9.2).
BB_DEFAULTS: dict[str, Any] = {
    "command": None,          # pending select_path / cancel / start_tour / stop_tour (a dict)
    "home_request": None,     # pending Go Home press (a dict) or None
    "pause_request": None,    # pending pause / resume (a dict) or None
    "paused": False,          # the tree is paused (owned by Pause; set by HoldEStop on release)
    "estop": False,           # e-stop engaged (ESTOP topic or an operator estop)
    "blocked": False,         # BLOCKED says: obstacle ahead and no progress
    "blocked_stamp": None,    # clock time of the BLOCKED message, seconds
    "obstacle_distance_m": None,
    "help_active": False,     # a help request is open (HELP ME shown)
    "help_done": None,        # pending operator "help done" (a dict) or None
    "help_rearm_until": None,  # clock time before which BLOCKED is ignored (or None)
    "battery_v": None,        # latest supply voltage, volts
    "battery_low": False,     # low with hysteresis (low < low_battery_v, ok >= battery_ok_v)
    "battery_home_pending": False,  # a low-battery go-home not yet started
    "curr_path": None,        # route id being followed (0 = Home, -1 = tour) or None
    "waypoint": 0,            # index of the current waypoint (the original's goal_cnt)
    "phase": "idle",          # follower phase: idle/moving/dwelling/held/finished/failed/...
    "goal_state": "",         # state of the last goal sent (pending/active/succeeded/...)
}


@dataclass
class TreeContext:
    """What every behaviour of one tree shares (constructor injection, no globals).

    Attributes:
        cfg: the ``[bt]`` config section.
        bus, clock: the application's bus and clock.
        navigator: the navigator (curio/nav/api.py) or None when navigation is not running.
        probe: tells whether a path leads to the held waypoint again (None: judge by BLOCKED).
        paths: the path manager.
        follower: drives the current route.
        sink: publishes status, progress and events.
        namespace: blackboard namespace of this tree (``/curio_<n>``).
        tree_kind: ``follow_path``, ``two_step`` or ``tour``.
        tour_route: the configured tour as a route (None when no stops are configured).
    """

    cfg: BtConfig
    bus: Bus
    clock: Clock
    navigator: Any
    paths: PathManager
    follower: PathFollower
    sink: StatusSink
    namespace: str
    tree_kind: str = "follow_path"
    tour_route: Route | None = None
    probe: WayProbe | None = None
    clients: list[py_trees.blackboard.Client] = field(default_factory=list)

    def key(self, name: str) -> str:
        """The absolute blackboard key of ``name`` in this tree's namespace."""
        return f"{self.namespace}/{name}"

    def accept(self, req: dict[str, Any] | None, action: str, message: str) -> None:
        """Tell the operator a command was carried out."""
        req = req or {}
        self.sink.event("bt.command_accepted", action=action, message=message,
                        request_id=req.get("request_id", ""), source=req.get("source", ""))

    def reject(self, req: dict[str, Any] | None, action: str, message: str) -> None:
        """Tell the operator a command was refused, and why."""
        req = req or {}
        log.info("command %s rejected: %s", action, message)
        self.sink.event("bt.command_rejected", action=action, message=message,
                        request_id=req.get("request_id", ""), source=req.get("source", ""))

    def home_route(self) -> Route:
        """Path 0 as a route."""
        return Route.from_path(self.paths.get(HOME_PATH_ID))

    def cancel_foreign_goal(self) -> GoalHandle | None:
        """Cancel a navigator goal that the tree did not send (paused or e-stopped)."""
        nav = self.navigator
        if nav is None:
            return None
        active = nav.active
        if active is not None and not active.done and not self.follower.owns(active):
            nav.cancel()
            return active  # type: ignore[no-any-return]
        return None


class CurioBehaviour(py_trees.behaviour.Behaviour):
    """Base: a blackboard client in the tree's namespace with declared keys.

    Args:
        name: the node's name (shown in snapshots).
        ctx: the tree's shared context.
        read: keys this behaviour reads.
        write: keys this behaviour writes (and may read).
    """

    def __init__(self, name: str, ctx: TreeContext, read: tuple[str, ...] = (),
                 write: tuple[str, ...] = ()) -> None:
        super().__init__(name)
        self.ctx = ctx
        self.bb = self.attach_blackboard_client(name=name, namespace=ctx.namespace)
        ctx.clients.append(self.bb)
        for key in read:
            self.bb.register_key(key=key, access=Access.READ)
        for key in write:
            self.bb.register_key(key=key, access=Access.WRITE)

    def get(self, key: str) -> Any:
        """Read a declared key."""
        return self.bb.get(key)

    def set(self, key: str, value: Any) -> None:
        """Write a declared key."""
        self.bb.set(key, value, overwrite=True)


# ---------------------------------------------------------------------------------------------
# Data feeds: bus -> blackboard. Each always returns SUCCESS within its tick.
# ---------------------------------------------------------------------------------------------


def _req(cmd: OperatorCommand, **extra: Any) -> dict[str, Any]:
    return {"action": cmd.action, "request_id": cmd.request_id, "source": cmd.source,
            "stamp": cmd.stamp, **extra}


class Operator2BB(CurioBehaviour):
    """Drain OPERATOR (reliable) each tick and turn each command into a request key.

    Validation that needs no tree state happens here, so a bad command is answered at once:
    unknown or empty paths, commands while paused or e-stopped, help-done with no help open,
    tour commands without a tour. Later commands in the same tick supersede earlier ones of the
    same kind (the earlier one is answered as superseded). Two ``toggle_pause`` presses within
    one tick count once (a double click), as in the original (§8 item 5).
    """

    def __init__(self, ctx: TreeContext, name: str = "Operator2BB") -> None:
        super().__init__(name, ctx,
                         read=("paused", "estop", "help_active", "battery_low", "battery_v",
                               "curr_path", "phase"),
                         write=("command", "home_request", "pause_request", "help_done",
                                "estop_operator"))
        self.sub: Subscription[OperatorCommand] = ctx.bus.subscribe(OPERATOR)
        self.set("estop_operator", None)
        self.pending: list[OperatorCommand] = []

    def inject(self, cmd: OperatorCommand) -> None:
        """Queue a command from inside the process (autostart), handled like the operator's."""
        self.pending.append(cmd)

    def close(self) -> None:
        """Stop receiving commands."""
        self.sub.close()

    def update(self) -> Status:
        """Handle every queued command in arrival order."""
        commands = self.pending + self.sub.drain()
        self.pending = []
        toggled = False
        for cmd in commands:
            if cmd.action == "toggle_pause":
                if toggled:
                    self.ctx.reject(_req(cmd), cmd.action,
                                    "Pause was pressed twice within one tick; counted once.")
                    continue
                toggled = True
            try:
                self._handle(cmd)
            except Exception as exc:  # a bad command must never stop the tree
                log.exception("operator command %s failed", cmd.action)
                self.ctx.reject(_req(cmd), cmd.action, f"The command failed: {exc}.")
        return Status.SUCCESS

    def _paused_effective(self) -> bool:
        req = self.get("pause_request")
        if req is not None:
            return bool(req["action"] == "pause")
        return bool(self.get("paused"))

    def _supersede(self, key: str, by: str) -> None:
        old = self.get(key)
        if old is not None:
            self.ctx.reject(old, old["action"], f"Replaced by a later {by} command.")
        self.set(key, None)

    def _handle(self, cmd: OperatorCommand) -> None:
        ctx = self.ctx
        action = cmd.action
        estop = bool(self.get("estop"))
        paused = self._paused_effective()
        if action in ("pause", "resume", "toggle_pause"):
            wanted = action
            if action == "toggle_pause":
                wanted = "resume" if paused else "pause"
            if wanted == "resume" and not paused and self.get("help_active"):
                self.set("help_done", _req(cmd, action="help_done"))  # Resume = help done
                return
            if wanted == "resume" and estop:
                ctx.reject(_req(cmd), action, "The e-stop is engaged: release it first.")
                return
            self.set("pause_request", _req(cmd, action=wanted))
        elif action == "estop":
            self.set("estop_operator", cmd.stamp)
        elif action == "release_estop":
            self.set("estop_operator", None)
        elif action == "go_home":
            if estop:
                ctx.reject(_req(cmd), action, "The e-stop is engaged: release it first, then "
                                              "press Go Home.")
            elif paused:
                ctx.reject(_req(cmd), action, "The rover is paused: press Resume first, then "
                                              "Go Home.")
            else:
                self._supersede("home_request", "Go Home")
                self._supersede("command", "Go Home")
                self.set("home_request", _req(cmd))
        elif action in ("select_path", "start_tour", "stop_tour", "cancel"):
            self._route_command(cmd, estop, paused)
        elif action == "help_done":
            if not self.get("help_active"):
                ctx.reject(_req(cmd), action, "The rover is not waiting for help.")
            else:
                self.set("help_done", _req(cmd))
        elif action == "goto":
            if estop or paused:
                what = "the e-stop is engaged" if estop else "the rover is paused"
                ctx.reject(_req(cmd), action, f"Not moving: {what}. The goal was cancelled; "
                                              "press Resume first, then send it again.")
            elif ctx.follower.active and ctx.follower.route is not None:
                ctx.accept(_req(cmd), action, f"Leaving {ctx.follower.route.name} for the "
                                              "goal you set.")
        else:  # pragma: no cover - OperatorAction is closed
            ctx.reject(_req(cmd), action, f"Unknown command '{action}'.")

    def _route_command(self, cmd: OperatorCommand, estop: bool, paused: bool) -> None:
        ctx = self.ctx
        action = cmd.action
        if ctx.tree_kind == "two_step":
            ctx.reject(_req(cmd), action, "The two-step tree only patrols its two goals (Pause "
                                          "stops it, Go Home sends it home); paths and tours "
                                          "need bt.tree = 'follow_path' or 'tour'.")
            return
        if action in ("select_path", "start_tour"):
            if estop:
                ctx.reject(_req(cmd), action, "The e-stop is engaged: release it first.")
                return
            if paused:
                what = "choose the path" if action == "select_path" else "start the tour"
                ctx.reject(_req(cmd), action, f"The rover is paused: press Resume first, then "
                                              f"{what}.")
                return
            if ctx.tree_kind == "tour" and self.get("battery_low"):
                volts = self.get("battery_v")
                ctx.reject(_req(cmd), action,
                           f"The battery is low ({volts:.2f} V): the rover stays home until it "
                           f"is above {ctx.cfg.battery_ok_v:.2f} V.")
                return
        if action == "select_path":
            if cmd.path_id is None:
                ctx.reject(_req(cmd), action, "Choose a path number.")
                return
            try:
                path = ctx.paths.get(cmd.path_id)
            except PathError as exc:
                ctx.reject(_req(cmd, path_id=cmd.path_id), action, str(exc))
                return
            if not path.waypoints:
                ctx.reject(_req(cmd, path_id=cmd.path_id), action,
                           f"Path {path.id} ({path.name}) has no waypoints yet; add some on "
                           "the map first.")
                return
            if cmd.path_id == HOME_PATH_ID:
                self._supersede("command", "path")
                self._supersede("home_request", "path")
                self.set("home_request", _req(cmd))
                return
        elif action in ("start_tour", "stop_tour"):
            if ctx.tree_kind != "tour":
                ctx.reject(_req(cmd), action, f"This tree has no tour (bt.tree = "
                                              f"'{ctx.tree_kind}'; use 'tour').")
                return
            if action == "start_tour" and ctx.tour_route is None:
                ctx.reject(_req(cmd), action, "No tour stops are configured (bt.tour_stops).")
                return
            if action == "stop_tour" and not (self.get("curr_path") == TOUR_ROUTE_ID
                                              and ctx.follower.active):
                ctx.reject(_req(cmd), action, "No tour is running.")
                return
        self._supersede("command", "path")
        self._supersede("home_request", "path")
        self.set("command", _req(cmd, path_id=cmd.path_id))


class Blocked2BB(CurioBehaviour):
    """Copy the latest BLOCKED state (default: not blocked) and its stamp to the blackboard."""

    def __init__(self, ctx: TreeContext, name: str = "Blocked2BB") -> None:
        super().__init__(name, ctx, write=("blocked", "blocked_stamp", "obstacle_distance_m",
                                           "help_rearm_until"))

    def update(self) -> Status:
        """Never RUNNING: a missing detector means "not blocked" (§9.2)."""
        msg = self.ctx.bus.latest(BLOCKED)
        blocked = bool(msg.blocked) if msg is not None else False
        self.set("blocked", blocked)
        self.set("blocked_stamp", msg.stamp if msg is not None else None)
        self.set("obstacle_distance_m", msg.obstacle_distance_m if msg is not None else None)
        if not blocked and self.ctx.follower.driving:
            self.set("help_rearm_until", None)  # seen clear while driving: may ask again
        return Status.SUCCESS


class EStop2BB(CurioBehaviour):
    """``estop`` = the safety stage's latched ESTOP, or an operator e-stop it has not yet seen."""

    def __init__(self, ctx: TreeContext, name: str = "EStop2BB") -> None:
        super().__init__(name, ctx, read=("estop_operator",), write=("estop",))

    def update(self) -> Status:
        """Combine the two sources; the newer one wins."""
        msg = self.ctx.bus.latest(ESTOP)
        op_stamp = self.get("estop_operator")
        if msg is not None and (op_stamp is None or msg.stamp >= op_stamp):
            engaged = bool(msg.engaged)
        else:
            engaged = op_stamp is not None
        self.set("estop", engaged)
        return Status.SUCCESS


class Battery2BB(CurioBehaviour):
    """Low battery with hysteresis: low below ``low_battery_v``, ok again at ``battery_ok_v``.

    Going low raises ``battery.low`` and one pending go-home (the original's mock battery sent
    go-home at 5 Hz for ever, §9.7).
    """

    def __init__(self, ctx: TreeContext, name: str = "Battery2BB") -> None:
        super().__init__(name, ctx, write=("battery_v", "battery_low", "battery_home_pending"))

    def update(self) -> Status:
        """Track the voltage; never RUNNING."""
        msg = self.ctx.bus.latest(BATTERY)
        if msg is None:
            return Status.SUCCESS
        volts = float(msg.voltage_v)
        self.set("battery_v", round(volts, 3))
        low = bool(self.get("battery_low"))
        cfg = self.ctx.cfg
        if not low and volts < cfg.low_battery_v:
            self.set("battery_low", True)
            self.set("battery_home_pending", True)
            self.ctx.sink.event("battery.low", voltage_v=round(volts, 3),
                                message=f"Battery low ({volts:.2f} V): going home.")
        elif low and volts >= cfg.battery_ok_v:
            self.set("battery_low", False)
            self.set("battery_home_pending", False)
            self.ctx.sink.event("battery.ok", voltage_v=round(volts, 3),
                                message=f"Battery recovered ({volts:.2f} V).")
        return Status.SUCCESS


class Follower2BB(CurioBehaviour):
    """Mirror the follower's state (route, waypoint, phase, goal state) on the blackboard."""

    def __init__(self, ctx: TreeContext, name: str = "Goal2BB") -> None:
        super().__init__(name, ctx, write=("curr_path", "waypoint", "phase", "goal_state"))

    def update(self) -> Status:
        """Copy; never RUNNING."""
        self.refresh()
        return Status.SUCCESS

    def refresh(self) -> None:
        """Write the follower's current state."""
        f = self.ctx.follower
        self.set("curr_path", f.route_id)
        self.set("waypoint", f.index)
        self.set("phase", f.phase)
        self.set("goal_state", f.handle.state.value if f.handle is not None else "")


# ---------------------------------------------------------------------------------------------
# Priorities
# ---------------------------------------------------------------------------------------------


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
    rover is allowed (nothing moves on resume, §9.14).
    """

    def __init__(self, ctx: TreeContext, name: str = "Pause") -> None:
        super().__init__(name, ctx, write=("paused", "pause_request"))

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
        req = self.get("home_request")
        self.set("home_request", None)
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
    """Low battery: start the home path once per low episode (hysteresis in Battery2BB)."""

    def __init__(self, ctx: TreeContext, name: str = "Battery Home") -> None:
        super().__init__(name, ctx, read=("battery_v",), write=("battery_home_pending",))

    def update(self) -> Status:
        """Consume the pending go-home; SUCCESS."""
        self.set("battery_home_pending", False)
        f = self.ctx.follower
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
        req = self.get("command")
        self.set("command", None)
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


class IsBlocked(CurioBehaviour):
    """SUCCESS when the way is blocked and recovery has not freed it, and no re-arm delay runs.

    Blocked means: BLOCKED says blocked while a goal of ours is being driven, or the navigator
    gave the waypoint up because the way is blocked (no path, no progress, no admissible
    motion, after its recovery ladder). Never at a reached goal, never idle, never at start-up.
    """

    def __init__(self, ctx: TreeContext, name: str = "Blocked?") -> None:
        super().__init__(name, ctx, read=("blocked", "help_rearm_until"))

    def update(self) -> Status:
        """Check the flag and the follower."""
        f = self.ctx.follower
        if not ((self.get("blocked") and f.driving) or f.failed_blocked):
            return Status.FAILURE
        rearm = self.get("help_rearm_until")
        if rearm is not None and self.ctx.clock.now() < rearm:
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
