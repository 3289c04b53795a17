"""Data feeds: bus → blackboard, each always SUCCESS within its tick.

Data feeds (``Operator2BB``, ``Blocked2BB``, ``EStop2BB``, ``Battery2BB``, ``Follower2BB``)
always return SUCCESS in one tick: unlike the original's ToBlackboard (RUNNING until a message
arrives, §1.0, §9.2–9.3), no feed can stall another, a missing publisher leaves a safe default
("not blocked", "no e-stop", "battery unknown"), and operator commands arrive through a
reliable queue, each one answered by ``bt.command_accepted`` or ``bt.command_rejected`` with a
sentence for the operator — every action, the e-stop, its release and a single goal included,
so a command's ``request_id`` always gets exactly one answer.
"""

from __future__ import annotations

import logging
from typing import Any

from py_trees.common import Status

from curio.core.bus import Subscription
from curio.core.messages import OperatorCommand
from curio.core.topics import BATTERY, BLOCKED, ESTOP, OPERATOR
from curio.power.model import battery_level

from .context import CurioBehaviour, TreeContext
from .follower import TOUR_ROUTE_ID
from .paths import HOME_PATH_ID, PathError

__all__ = ["Battery2BB", "Blocked2BB", "EStop2BB", "Follower2BB", "Operator2BB"]

log = logging.getLogger("curio.bt")


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
                               "curr_path", "phase", "lost"),
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
        self._refuse_held()
        return Status.SUCCESS

    def _refuse_held(self) -> None:
        """A path, tour or Go Home still waiting while a pause, an e-stop or being lost holds the
        rover is answered now, refused: the branches that would carry it out do not run while
        the rover is held, so it would wait unanswered for as long as the hold lasts (found by
        ``curio soak``: a command pressed in the same tick as Pause, and a kiosk's tour while
        the rover was lost, were never answered). The route the rover was on when it got lost
        is not a command: it is held and resumes once the rover is found."""
        if self.get("estop") or self.get("estop_operator") is not None:
            why = "The e-stop was engaged before it started: release it, then send it again."
        elif self._paused_effective():
            why = "The rover was paused before it started: press Resume, then send it again."
        elif self.get("lost"):
            why = ("I am not sure where I am: set my position on the map (or press Relocalise), "
                   "then send it again.")
        else:
            return
        for key in ("command", "home_request"):
            old = self.get(key)
            if old is not None:
                self.ctx.reject(old, old["action"], why)
                self.set(key, None)

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
            # An earlier Pause or Resume of this tick is answered, not dropped (the 24-hour
            # soak: two operators paused within one tick and one was never answered).
            self._supersede("pause_request", "Pause" if wanted == "pause" else "Resume")
            self.set("pause_request", _req(cmd, action=wanted))
        elif action == "estop":
            self.set("estop_operator", cmd.stamp)
            ctx.accept(_req(cmd), action, "E-stop engaged: the rover stopped.")
        elif action == "release_estop":
            self.set("estop_operator", None)
            ctx.accept(_req(cmd), action, "E-stop released.")
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
            else:  # the navigator takes the goal itself (nav.goal_* follow)
                where = f" ({cmd.goal.x:.2f}, {cmd.goal.y:.2f})" if cmd.goal else ""
                ctx.accept(_req(cmd), action, f"Going to the goal you set{where}.")
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
    """Battery levels with hysteresis (:func:`curio.power.model.battery_level`): low below
    ``low_battery_v``, critical below ``critical_battery_v``, ok again at ``battery_ok_v``.

    Going low raises ``battery.low`` and one pending go-home or dock (the original's mock
    battery sent go-home at 5 Hz for ever, §9.7); going critical raises ``battery.critical``.
    ``battery_low`` holds for both levels (route commands are refused with the voltage).
    """

    def __init__(self, ctx: TreeContext, name: str = "Battery2BB") -> None:
        super().__init__(name, ctx, write=("battery_v", "battery_low", "battery_home_pending",
                                           "battery_critical"))
        self.level = "ok"

    def update(self) -> Status:
        """Track the voltage; never RUNNING."""
        msg = self.ctx.bus.latest(BATTERY)
        if msg is None:
            return Status.SUCCESS
        volts = float(msg.voltage_v)
        self.set("battery_v", round(volts, 3))
        cfg = self.ctx.cfg
        before = self.level
        self.level = battery_level(before, volts, cfg.low_battery_v, cfg.battery_ok_v,
                                   cfg.critical_battery_v)
        if self.level == before:
            return Status.SUCCESS
        where = "the dock" if self.ctx.docker is not None else "home"
        self.set("battery_low", self.level != "ok")
        self.set("battery_critical", self.level == "critical")
        if before == "ok":
            self.set("battery_home_pending", True)
            self.ctx.sink.event("battery.low", voltage_v=round(volts, 3),
                                message=f"Battery low ({volts:.2f} V): going to {where} to "
                                        "charge.")
        if self.level == "critical":
            self.ctx.sink.event("battery.critical", voltage_v=round(volts, 3),
                                message=f"Battery critical ({volts:.2f} V): stopping here; "
                                        "please take me to my charger.")
        elif self.level == "ok":
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
