"""Unattended operation in the tree: battery on every tree, the dock, lost and found.

Feeds (SUCCESS every tick): :class:`Localization2BB` (``lost``: localisation lost, or uncertain
with a wide spread, for a while, or a jump of its estimate; found again when ``ok``, or after the
operator set the pose) and
:class:`Dock2BB` (``docked``, ``charging`` from the docker). ``Battery2BB`` (levels with
hysteresis) is in :mod:`curio.bt.feeds` and now runs in every tree.

Branches (:func:`unattended_branches`, placed after E-stop and Pause in every tree):

* **Battery critical** — :class:`BatteryCritical`: stop where it is (the route is abandoned,
  docking cancelled), ask for help (``help.requested``, reason ``battery_critical``); until
  the battery is charged back to ``battery_ok_v``. On the dock it only waits.
* **Lost** — :class:`Relocalise` (``lost``: see :class:`Localization2BB`): hold the route, say
  so (status ``Lost: ...``, event ``localization.lost``), ask the localiser to start again
  (around the pose before a jump; a global search when uncertain for long; nothing when it
  searches by itself), turn in place through at most ``relocalise_rotation_rad`` so the lidar
  sees more, and after ``relocalise_timeout_s`` ask a person (``help.requested``, reason
  ``lost``). Found (the feed clears ``lost``): ``localization.found``, the held route resumes
  where it was. While paused this branch is held; Pause then reports and searches the same way
  without turning (:class:`LostReport`, shared by both).
* **Battery** (low) — ``BatteryHome``: with a dock, asks to dock (``dock_request``, reason
  ``battery``) and abandons the route; without one, drives path 0 as before.
* **Dock** — :class:`DockAction`: drives the docker (staging, approach, retries) until docked;
  a failed docking asks for help (reason ``dock_failed``). Go Home with a dock is
  :class:`RequestDock` (reason ``home``), which a route command may replace.
* **Undock** — :class:`Undock`, guarded by :class:`NeedsUndock`: a route command or a goal of
  the dashboard while docked backs the rover out of the dock first, then carries on.
* **Docked** (before Idle) — :class:`ShowDocked`: status ``Docked`` or ``Charging (63 %)``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import operator
from collections.abc import Callable
from typing import Any

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import PoseWithCovariance, Twist
from curio.core.topics import (
    CMD_VEL_NAV,
    INITIAL_POSE,
    LOCALIZATION,
    MAP_TO_ODOM,
    ODOM,
    POSE,
    POWER,
)

from .context import CurioBehaviour, TreeContext
from .guards import check_key

__all__ = ["BatteryCritical", "Dock2BB", "DockAction", "Localization2BB", "LostReport",
           "NeedsUndock", "Relocalise", "RequestDock", "ShowDocked", "Spinner", "Undock",
           "docked_branch", "lost_report", "unattended_branches", "unattended_feeds",
           "undock_branch"]

log = logging.getLogger("curio.bt.unattended")

GLOBAL_STD_XY_M = 1.0e3  # an INITIAL_POSE this wide asks the localiser for a global search
HINT_STD_XY_M = 0.3      # after a jump: start again around the pose before it, this wide
HINT_STD_YAW_RAD = 0.3


# --- feeds -------------------------------------------------------------------------------------


class Localization2BB(CurioBehaviour):
    """``lost`` from the localiser (``/localization``, ``/tf/map_odom``, ``/pose``, ``/odom``).

    Lost when the state is ``lost`` for ``lost_confirm_s``; or ``uncertain`` with a spread
    above ``lost_std_xy_m`` for ``lost_uncertain_s`` (a fit degrading slowly); or at once when
    the localiser's correction jumps by more than ``JUMP_M`` / ``JUMP_RAD`` while it was
    tracking (it put the rover somewhere else: a look-alike place where furniture moved, or
    the right place after a drift; either way the rover stops and checks). After a jump
    ``lost_hint`` holds where the rover was before it, moved on by odometry (the Relocalise
    behaviour starts from there), and the estimate must come back near it (or near a pose the
    operator sets) to count: a far-away answer alone is not trusted — unless the localiser,
    started again there, says ``lost`` (its poor-fit count ran out there): the scan does not
    fit where the rover was, so it was carried away (lifted, pushed), and the localiser's
    whole-map answer is the evidence left (before, a carried rover stayed lost and out of
    service for good, asking for help, while the localiser knew where it was) — or says
    ``ok`` there but not at the hint itself (see :meth:`_near_anchor`): a look-alike beside
    the old place, so the tree asks for the whole map (``localization.search``) and that
    search's answer counts.
    Found again when, with the turn in place over
    (``relocalising`` false), the localiser has not been ``lost``, has not jumped and has been
    confident (``ok``, or a spread within half of ``lost_std_xy_m``) for ``found_confirm_s``;
    after a jump only ``ok`` counts until a person sets the pose: a small spread with a
    mediocre fit near the old pose can be a look-alike place after a carry (the soak saw a
    rover "found" that way 7 m from the truth, which then drove 10 m off).
    No localiser (or state ``off``): never lost.
    """

    JUMP_M = 0.5
    JUMP_RAD = 0.5
    HINT_XY_M = 0.15
    HINT_YAW_RAD = 0.1
    SETTLE_S = 3.0  # a pose set on /initialpose is applied (the correction jumps) within this

    def __init__(self, ctx: TreeContext, name: str = "Localization2BB") -> None:
        super().__init__(name, ctx, read=("relocalising",), write=("lost", "lost_hint"))
        self._since: dict[str, float | None] = {"lost": None, "bad": None, "good": None}
        self._correction: Pose2D | None = None
        self._initial_stamp = -math.inf
        self._track: tuple[Pose2D, Pose2D] | None = None  # (pose in map, odometry) last tick
        self._anchor: tuple[Pose2D, Pose2D] | None = None  # after a jump: (pose, odometry)
        # After a jump, until found or a person sets the pose: found needs ``ok``, not only a
        # small spread (a mediocre fit near the old pose may be a look-alike place).
        self._need_ok = False
        self._expect_jump = False
        self._searching = False  # a whole-map search was asked for and has not settled yet
        self._search_asked = False  # ... and the tree has not taken note of it yet
        self._whole_map_s = -math.inf  # when the tree last asked for the whole map itself

    def _held(self, key: str, on: bool, now: float) -> float:
        """How long condition ``key`` has held (0 when it does not hold now)."""
        if not on:
            self._since[key] = None
            return 0.0
        start = self._since[key]
        if start is None:
            self._since[key] = start = now
        return now - start

    def _jumped(self, now: float) -> float | None:
        """How far the map→odom correction jumped since the last tick (None: it did not). The
        first jump within ``SETTLE_S`` of a pose set on ``/initialpose`` is that pose being
        applied, not a jump; during a whole-map search (an ``/initialpose`` as wide as
        ``GLOBAL_STD_XY_M``, until the localiser is ``ok`` again) the estimate moves from place
        to place by design, so nothing counts as a jump — narrowing the search back to where the
        rover was would undo the operator's (or the tree's own) Relocalise."""
        bus = self.ctx.bus
        ip = bus.latest(INITIAL_POSE)
        if ip is not None and ip.stamp > self._initial_stamp:
            self._initial_stamp = ip.stamp
            self._expect_jump = True
            self._since["good"] = None  # judge the localiser afresh from here
            self._searching = self._search_asked = ip.covariance[0] >= GLOBAL_STD_XY_M ** 2
            odom_now = bus.latest(ODOM)
            if ip.covariance[0] < GLOBAL_STD_XY_M and odom_now is not None and self.get("lost") \
                    and self._anchor is not None:
                self._anchor = (ip.pose, odom_now.pose)  # the operator (or the tree) set the pose
            hint = self.get("lost_hint")
            if hint is None or ip.pose.distance_to(Pose2D(*hint)) > 1e-6:
                self._need_ok = False  # a person set the pose (or asked for the whole map)
        corr_msg = bus.latest(MAP_TO_ODOM)
        corr = corr_msg.transform if corr_msg is not None else None
        prev, self._correction = self._correction, corr
        if now - self._initial_stamp > self.SETTLE_S:
            self._expect_jump = False
        status = bus.latest(LOCALIZATION)
        if self._searching and status is not None and status.state == "ok" \
                and status.stamp > self._initial_stamp:
            self._searching = False
        odom = bus.latest(ODOM)
        if prev is None or corr is None or odom is None or self._searching:
            return None
        # Where the rover is in map under each correction (a small turn of the correction
        # moves the odom origin far when the rover is far from it: compare the rover).
        before, after = prev @ odom.pose, corr @ odom.pose
        dist = before.distance_to(after)
        if dist > self.JUMP_M or abs(wrap_angle(after.yaw - before.yaw)) > self.JUMP_RAD:
            if self._expect_jump:
                self._expect_jump = False
                return None
            return dist
        return None

    def _hint(self) -> tuple[float, float, float] | None:
        """Where the rover was before the jump, moved on by the odometry since."""
        odom = self.ctx.bus.latest(ODOM)
        if self._track is None or odom is None:
            return None
        pose, odom_then = self._track
        here = pose @ (odom_then.inverse() @ odom.pose)
        return (here.x, here.y, here.yaw)

    def _near_anchor(self) -> bool:
        """After a jump, the estimate must come back near where the rover was (or where the
        operator put it), moved on by odometry: within ``2 JUMP_M`` of an operator's pose
        (a click gives a rough pose); within ``HINT_XY_M`` and ``HINT_YAW_RAD`` of the
        tree's own hint — a slip of the estimate while the rover stood or drove on leaves it
        exactly there (the odometry is good to centimetres and a degree over the turn),
        while the look-alike the particles settle on near the old place after a carry (a
        corridor seen the other way round) is 0.2–0.4 m and 0.2–0.4 rad off. A far-away
        answer is not trusted alone."""
        if self._anchor is None:
            return True
        pose, odom = self.ctx.bus.latest(POSE), self.ctx.bus.latest(ODOM)
        if pose is None or odom is None:
            return False
        anchor, odom_then = self._anchor
        expected = anchor @ (odom_then.inverse() @ odom.pose)
        hint = self.get("lost_hint")
        if hint is None or anchor.distance_to(Pose2D(*hint)) > 1e-6:
            return pose.pose.distance_to(expected) <= 2 * self.JUMP_M
        return (pose.pose.distance_to(expected) <= self.HINT_XY_M
                and abs(wrap_angle(pose.pose.yaw - expected.yaw)) <= self.HINT_YAW_RAD)

    def _remember(self) -> None:
        pose, odom = self.ctx.bus.latest(POSE), self.ctx.bus.latest(ODOM)
        self._track = (pose.pose, odom.pose) if pose is not None and odom is not None else None

    def update(self) -> Status:
        """Never RUNNING."""
        msg = self.ctx.bus.latest(LOCALIZATION)
        now = self.ctx.clock.now()
        cfg = self.ctx.cfg
        jump = self._jumped(now)
        if msg is None or msg.state == "off":
            self._clear_lost()
            return Status.SUCCESS
        lost_for = self._held("lost", msg.state == "lost", now)
        bad_for = self._held("bad", msg.state == "uncertain"
                             and msg.std_xy_m > cfg.lost_std_xy_m, now)
        # After the tree asked for the whole map, a status from before the request is stale.
        good_for = self._held("good", jump is None and msg.stamp > self._whole_map_s
                              and msg.state != "lost" and (
            msg.state == "ok" or (not self._need_ok
                                  and msg.std_xy_m <= 0.5 * cfg.lost_std_xy_m)), now)
        asked, self._search_asked = self._search_asked, False
        if not self.get("lost") and asked:
            # Relocalise pressed (or asked for by the CLI): the rover no longer knows where it
            # is. Lost at once, with no hint: the turn in place helps the localiser's search.
            self.ctx.sink.event("localization.search", message="Searching the whole map for "
                                "where I am.")
            self.set("lost_hint", None)
            self._anchor = None
            self.set("lost", True)
        elif not self.get("lost"):
            if jump is not None:
                self.ctx.sink.event("localization.jump", distance_m=round(jump, 3),
                                    message="My position estimate jumped: checking where I "
                                            "am.")
                hint = self._hint()
                self.set("lost_hint", hint)
                odom = self.ctx.bus.latest(ODOM)
                self._anchor = ((Pose2D(*hint), odom.pose) if hint is not None
                                and odom is not None else None)
                self._need_ok = True
            else:
                self._remember()
                self.set("lost_hint", None)
            if (jump is not None or (msg.state == "lost" and lost_for >= cfg.lost_confirm_s)
                    or bad_for >= cfg.lost_uncertain_s):
                self.set("lost", True)
        elif self._anchor is not None and msg.state == "lost" and msg.stamp > self._initial_stamp:
            # Started again at the anchor (the tree's hint or an operator's pose), the localiser
            # finds the scan does not fit there: the rover was moved; its answer counts.
            self._anchor = None
            self.ctx.sink.event("localization.search", message="The view does not fit where I "
                                "was: I must have been moved. Searching the whole map.")
        elif not self.get("relocalising") and good_for >= cfg.found_confirm_s and \
                self._near_anchor():
            self._clear_lost()
            self._anchor = None
            self._need_ok = False
            self._remember()
        elif self._anchor is not None and good_for >= cfg.found_confirm_s and \
                msg.stamp > self._initial_stamp and not self._near_anchor():
            # Started again at the anchor, the localiser is sure of a pose that is not the
            # anchor: a look-alike near the old place, or the rover was moved. Neither is
            # trusted: the whole map decides (its ranking by the fine fit finds the truth).
            self._anchor = None
            self._whole_map_s = now
            self.ctx.sink.event("localization.search", message="What I see fits near where I "
                                "was, but not as I was: I must have been moved. Searching the "
                                "whole map.")
            self.ctx.bus.publish(INITIAL_POSE, PoseWithCovariance.from_std(
                now, Pose2D(), GLOBAL_STD_XY_M, math.pi))
        return Status.SUCCESS

    def _clear_lost(self) -> None:
        """Not lost any more: the lost episode being reported ends here (found), whichever
        branch held the rover meanwhile."""
        self.set("lost", False)
        report = self.ctx.lost
        if report is not None and report.active:
            report.end()


class Dock2BB(CurioBehaviour):
    """``docked`` and ``charging`` from the docker (False without one)."""

    def __init__(self, ctx: TreeContext, name: str = "Dock2BB") -> None:
        super().__init__(name, ctx, write=("docked", "charging"))

    def update(self) -> Status:
        """Never RUNNING."""
        docker = self.ctx.docker
        docked = docker is not None and docker.docked
        self.set("docked", docked)
        power = self.ctx.bus.latest(POWER)
        self.set("charging", bool(docked and power is not None and power.charging))
        return Status.SUCCESS


# --- turning in place ----------------------------------------------------------------------------


class Spinner:
    """Turns the rover in place through up to ``angle_rad`` (odometry) on ``/cmd_vel_nav`` at
    10 Hz, in a task the behaviour starts and polls (it never awaits); it gives up after twice
    the time the turn should take (something in the way). Without a running event loop (unit
    tests that tick by hand) it does nothing and reports done."""

    def __init__(self, ctx: TreeContext) -> None:
        self.ctx = ctx
        self._task: asyncio.Task[None] | None = None
        self.turned_rad = 0.0

    @property
    def done(self) -> bool:
        """Not turning (finished, stopped, or never started)."""
        return self._task is None or self._task.done()

    def start(self, angle_rad: float, speed_radps: float) -> None:
        """Start turning (counter-clockwise)."""
        self.stop()
        self.turned_rad = 0.0
        if angle_rad <= 0.0:
            return
        with contextlib.suppress(RuntimeError):  # no loop: nothing turns
            asyncio.get_running_loop()
            self._task = asyncio.ensure_future(self._turn(angle_rad, speed_radps))

    def stop(self) -> None:
        """Stop turning now."""
        if self._task is not None and not self._task.done():
            self._task.cancel()
            self._zero()
        self._task = None

    def _zero(self) -> None:
        self.ctx.bus.publish(CMD_VEL_NAV, Twist(self.ctx.clock.now(), 0.0, 0.0,
                                                source="relocalise"))

    async def _turn(self, angle_rad: float, speed_radps: float) -> None:
        bus, clock = self.ctx.bus, self.ctx.clock
        last: float | None = None
        # Something in the way may hold the turn (the safety stage): give up after twice the
        # time the turn should take.
        deadline = clock.now() + 2.0 * angle_rad / speed_radps + 5.0
        try:
            async for now in clock.every(0.1):
                if now > deadline:
                    break
                odom = bus.latest(ODOM)
                if odom is not None:
                    if last is not None:
                        self.turned_rad += abs(wrap_angle(odom.pose.yaw - last))
                    last = odom.pose.yaw
                if self.turned_rad >= angle_rad:
                    break
                bus.publish(CMD_VEL_NAV, Twist(now, 0.0, speed_radps, source="relocalise"))
        finally:
            self._zero()


# --- battery critical ---------------------------------------------------------------------------


class BatteryCritical(CurioBehaviour):
    """Critical battery: stop where it is and ask for help (RUNNING until charged)."""

    def __init__(self, ctx: TreeContext, name: str = "Battery Critical") -> None:
        super().__init__(name, ctx, read=("battery_v", "docked", "battery_critical"),
                         write=("dock_request",))
        self.asked = False

    def initialise(self) -> None:
        """Stop everything; ask for help unless on the dock."""
        ctx = self.ctx
        volts = self.get("battery_v")
        if ctx.follower.active:
            ctx.follower.stop()
        if ctx.docker is not None and ctx.docker.busy:
            ctx.docker.cancel("battery critical")
        self.set("dock_request", None)
        ctx.cancel_foreign_goal()
        self.asked = False
        if not self.get("docked"):
            self.asked = True
            ctx.sink.event("help.requested", reason="battery_critical", trigger="battery",
                           message="My battery is almost empty: please take me to my "
                                   "charger.",
                           voltage_v=volts)
        self._status()

    def _status(self) -> None:
        volts = self.get("battery_v")
        if self.get("docked"):
            self.ctx.sink.status(f"Battery critical ({volts:.2f} V): charging", "charging")
        else:
            self.ctx.sink.status(f"Battery critical ({volts:.2f} V): please take me to my "
                                 "charger", "needs_help")

    def update(self) -> Status:
        """Hold; refuse the dashboard's goals."""
        self.ctx.cancel_foreign_goal()
        self._status()
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        """Charged (or pre-empted): close the help request."""
        if self.asked:
            self.asked = False
            charged = not self.get("battery_critical")
            self.ctx.sink.event("help.resolved", reason="charged" if charged else "preempted",
                                message="Thanks!" if charged else "Help is no longer needed.",
                                help_reason="battery_critical")


# --- lost and found -----------------------------------------------------------------------------


class LostReport:
    """What a lost rover says and asks, moving or not: the localiser asked to search, the event
    and status, a person asked after ``relocalise_timeout_s``, and found or withdrawn at the
    end. :class:`Relocalise` adds the hold and the turn; :class:`~curio.bt.actions.Pause` uses
    it alone while paused (a paused rover carried elsewhere must still say it is lost and let
    the localiser search, without moving).

    Args:
        ctx: the tree's context.
        get: the owning behaviour's blackboard read (keys ``lost``, ``lost_hint``).
    """

    def __init__(self, ctx: TreeContext, get: Callable[[str], Any]) -> None:
        self.ctx = ctx
        self.get = get
        self.active = False
        self.started_s = 0.0
        self.asked = False
        self.paused = False

    def begin(self, turning_rad: float, paused: bool = False) -> None:
        """Lost now: ask the localiser, say so (``turning_rad``: the turn that helps). An
        episode already being reported (lost, then paused or resumed) goes on: said once."""
        ctx = self.ctx
        if self.active:
            self.paused = paused
            self._status()
            return
        self.active, self.asked, self.paused = True, False, paused
        self.started_s = ctx.clock.now()
        self._ask_localiser()
        if paused:
            message = "I am not sure where I am. I stay paused; the search goes on."
        else:
            message = "I am not sure where I am: looking around to find my way."
        ctx.sink.event("localization.lost", message=message, turning_rad=round(turning_rad, 3),
                       paused=paused)
        if ctx.follower.speak is not None:
            ctx.follower.speak("I am not sure where I am." + (
                "" if paused else " Let me look around."))
        self._status()

    def _status(self) -> None:
        ctx = self.ctx
        if self.asked:
            ctx.sink.status(("Paused and lost" if self.paused else "Lost")
                            + ": please set my position on the map or press Relocalise",
                            "needs_help")
        elif self.paused:
            ctx.sink.status("Paused and lost: searching for my position", "paused")
        else:
            ctx.sink.status("Lost: looking around to find my way", "lost")

    def _ask_localiser(self) -> None:
        """After a jump: start again around where the rover was (it stopped at once). Uncertain
        for long: a global search. Lost: nothing (the localiser searches by itself,
        ``localization.auto_relocalize``)."""
        ctx = self.ctx
        hint = self.get("lost_hint")
        status = ctx.bus.latest(LOCALIZATION)
        asked = ctx.bus.latest(INITIAL_POSE)
        if hint is None and asked is not None and asked.covariance[0] >= GLOBAL_STD_XY_M ** 2 \
                and ctx.clock.now() - asked.stamp <= Localization2BB.SETTLE_S:
            return  # a whole-map search was just asked for: it is running
        if hint is not None:
            std_xy, std_yaw, pose = HINT_STD_XY_M, HINT_STD_YAW_RAD, Pose2D(*hint)
        elif status is None or status.state != "lost":
            std_xy, std_yaw, pose = GLOBAL_STD_XY_M, math.pi, Pose2D()
        else:
            return
        ctx.bus.publish(INITIAL_POSE, PoseWithCovariance.from_std(ctx.clock.now(), pose, std_xy,
                                                                  std_yaw))

    def update(self, turn_done: bool = True) -> None:
        """Ask a person once the turn is over and ``relocalise_timeout_s`` has passed."""
        ctx = self.ctx
        now = ctx.clock.now()
        if not self.asked and turn_done and now - self.started_s >= ctx.cfg.relocalise_timeout_s:
            self.asked = True
            ctx.sink.event("help.requested", reason="lost", trigger="lost",
                           message="I am lost: please set my position on the map or press "
                                   "Relocalise.")
        self._status()

    def end(self) -> None:
        """Found (``lost`` cleared) or pre-empted: say which; withdraw the help request."""
        ctx = self.ctx
        found = not self.get("lost")
        if found:
            ctx.sink.event("localization.found", message="I know where I am again.",
                           after_s=round(ctx.clock.now() - self.started_s, 2))
        if self.asked:
            ctx.sink.event("help.resolved", reason="found" if found else "preempted",
                           message="Thanks!" if found else "Help is no longer needed.",
                           help_reason="lost",
                           waited_s=round(ctx.clock.now() - self.started_s, 3))
        self.active = self.asked = False


def lost_report(ctx: TreeContext, get: Callable[[str], Any]) -> LostReport:
    """The tree's one :class:`LostReport` (created by the first behaviour that asks)."""
    if ctx.lost is None:
        ctx.lost = LostReport(ctx, get)
    report: LostReport = ctx.lost
    return report


class Relocalise(CurioBehaviour):
    """Lost: hold, relocalise in place (bounded turn), then ask for help; found: resume."""

    def __init__(self, ctx: TreeContext, name: str = "Relocalise") -> None:
        super().__init__(name, ctx, read=("lost", "docked", "lost_hint"),
                         write=("relocalising",))
        self.spinner = Spinner(ctx)
        self.report = lost_report(ctx, self.get)
        self.held = False

    def initialise(self) -> None:
        """Stop, say so, start the global search and the turn."""
        ctx = self.ctx
        cfg = ctx.cfg
        self.held = ctx.follower.active
        if self.held:
            ctx.follower.hold("lost")
        if ctx.docker is not None and ctx.docker.busy:
            ctx.docker.cancel("localisation lost")
        ctx.cancel_foreign_goal()
        turn = 0.0 if self.get("docked") else cfg.relocalise_rotation_rad
        self.report.begin(turn)
        self.spinner.start(turn, cfg.relocalise_speed_radps)
        self.set("relocalising", not self.spinner.done)

    def update(self) -> Status:
        """Turn, wait for the localiser, then ask a person."""
        self.ctx.cancel_foreign_goal()
        self.set("relocalising", not self.spinner.done)
        self.report.update(self.spinner.done)
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        """Found: resume the route; pre-empted: withdraw the help request."""
        ctx = self.ctx
        self.spinner.stop()
        self.set("relocalising", False)
        found = not self.get("lost")  # the feed has ended the lost episode
        if found and self.held and ctx.follower.phase == "held":
            ctx.follower.resume()
        elif found:  # nothing to resume: the status must not keep saying "Lost"
            ctx.sink.status("I know where I am again.", "idle")
        self.held = False


# --- the dock -----------------------------------------------------------------------------------


class RequestDock(CurioBehaviour):
    """Go Home with a dock: ask to dock (reason ``home``); SUCCESS."""

    def __init__(self, ctx: TreeContext, name: str = "Request Dock") -> None:
        super().__init__(name, ctx, write=("home_request", "dock_request"))

    def update(self) -> Status:
        """Consume the press."""
        ctx = self.ctx
        req = self.take("home_request")
        if ctx.docker.docked:
            ctx.accept(req, "go_home", "Already home, on the dock.")
            return Status.SUCCESS
        if ctx.follower.active:
            ctx.follower.stop()
        self.set("dock_request", {**(req or {}), "reason": "home"})
        ctx.accept(req, "go_home", "Going home to the dock.")
        return Status.SUCCESS


class DockAction(CurioBehaviour):
    """Dock: RUNNING while the docker works; SUCCESS docked; FAILURE failed (help asked) or
    replaced by a route command or a goal sent from the dashboard (Go Home's docking only:
    the person's newer say-so wins, no help is asked)."""

    def __init__(self, ctx: TreeContext, name: str = "Dock") -> None:
        super().__init__(name, ctx, read=("command", "battery_v"),
                         write=("dock_request", "home_request"))
        self.reason = ""

    def initialise(self) -> None:
        """Start docking."""
        req = self.get("dock_request") or {}
        self.reason = str(req.get("reason", "home"))
        self.ctx.docker.dock(self.reason)
        self._status()

    def _status(self) -> None:
        why = f"battery low ({self.get('battery_v')} V)" if self.reason == "battery" else ""
        d = self.ctx.docker
        what = "Going to the dock" if d.state == "staging" else \
            f"Docking (attempt {d.attempt})"
        self.ctx.sink.status(f"{what}: {why}" if why else what, "going_home")

    def update(self) -> Status:
        """Poll the docker."""
        ctx = self.ctx
        d = ctx.docker
        home = self.take("home_request")
        if home is not None:
            ctx.accept(home, "go_home", "Already going to the dock.")
        if self.reason == "home" and self.get("command") is not None:
            d.cancel("a route command replaced Go Home")
            self.set("dock_request", None)
            return Status.FAILURE
        if d.docked:
            self.set("dock_request", None)
            ctx.sink.status("Docked", "docked")
            return Status.SUCCESS
        if d.state == "failed":
            self.set("dock_request", None)
            ctx.sink.event("help.requested", reason="dock_failed", trigger="dock",
                           message=f"I could not dock: {d.detail}.")
            ctx.sink.status("Needs help: could not dock", "needs_help")
            return Status.FAILURE
        nav = ctx.navigator
        active = nav.active if nav is not None else None
        if self.reason == "home" and not d.busy and active is not None and not active.done:
            # The dashboard's goal replaced the way to the dock: it wins, as a route does.
            self.set("dock_request", None)
            return Status.FAILURE
        if not d.busy:  # cancelled from outside (e-stop handled above): try again
            d.dock(self.reason)
        self._status()
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        """Pre-empted (pause, e-stop, lost, critical): stop docking; the request stays."""
        if new_status == Status.INVALID and self.ctx.docker.busy:
            self.ctx.docker.cancel("pre-empted")


class NeedsUndock(CurioBehaviour):
    """SUCCESS when the rover is docked and something wants it to drive: a route command
    (``select_path``, ``start_tour``), a goal sent to the navigator by the dashboard, or (two-
    step tree) the patrol once the battery is fine."""

    def __init__(self, ctx: TreeContext, name: str = "Must undock?") -> None:
        super().__init__(name, ctx, read=("docked", "command", "battery_low", "dock_request"))

    def update(self) -> Status:
        """Check."""
        ctx = self.ctx
        if ctx.docker.state == "undocking":
            return Status.SUCCESS
        if not self.get("docked") or ctx.docker.busy:
            return Status.FAILURE
        cmd = self.get("command")
        if cmd is not None and cmd.get("action") in ("select_path", "start_tour"):
            return Status.SUCCESS
        nav = ctx.navigator
        active = nav.active if nav is not None else None
        if active is not None and not active.done and not ctx.follower.owns(active):
            return Status.SUCCESS
        if ctx.tree_kind == "two_step" and not self.get("battery_low") and \
                self.get("dock_request") is None:
            return Status.SUCCESS
        return Status.FAILURE


class Undock(CurioBehaviour):
    """Back out of the dock, then let the waiting command (or goal) go on: RUNNING while
    undocking, FAILURE when out (the branches below run in the same tick)."""

    def __init__(self, ctx: TreeContext, name: str = "Undock") -> None:
        super().__init__(name, ctx)
        self.goal: tuple[list[Pose2D], str] | None = None

    def initialise(self) -> None:
        """Hold the dashboard's goal (if any) and start undocking."""
        ctx = self.ctx
        nav = ctx.navigator
        active = nav.active if nav is not None else None
        self.goal = None
        if active is not None and not active.done and not ctx.follower.owns(active):
            self.goal = (list(active.poses), active.tag)
            nav.cancel()
        ctx.docker.undock()
        ctx.sink.status("Leaving the dock", "moving")

    def update(self) -> Status:
        """Wait for the docker."""
        d = self.ctx.docker
        if d.state == "undocking":
            return Status.RUNNING
        if self.goal is not None and self.ctx.navigator is not None:
            poses, tag = self.goal
            self.ctx.navigator.send_goal(poses, tag=tag)
        self.goal = None
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        """Pre-empted: stop backing out."""
        if new_status == Status.INVALID and self.ctx.docker.state == "undocking":
            self.ctx.docker.cancel("pre-empted")


class ShowDocked(CurioBehaviour):
    """On the dock: status ``Docked`` or ``Charging (63 %)``; RUNNING."""

    def __init__(self, ctx: TreeContext, name: str = "Show Docked") -> None:
        super().__init__(name, ctx, read=("charging",))

    def update(self) -> Status:
        """Report."""
        power = self.ctx.bus.latest(POWER)
        if self.get("charging") and power is not None:
            self.ctx.sink.status(f"Charging ({power.soc * 100:.0f} %)", "charging")
        else:
            self.ctx.sink.status("Docked", "docked")
        return Status.RUNNING


# --- branches -----------------------------------------------------------------------------------


def unattended_feeds(ctx: TreeContext) -> list[Behaviour]:
    """The feeds every tree gets (after the others)."""
    return [Localization2BB(ctx), Dock2BB(ctx)]


def unattended_branches(ctx: TreeContext, battery_branch: Behaviour,
                        home_branch: Behaviour) -> list[Behaviour]:
    """Battery critical, Lost, Battery (low), Dock and Go Home, for after E-stop and Pause.

    Args:
        ctx: the tree's context.
        battery_branch: the low-battery branch (its action asks to dock when there is a dock).
        home_branch: the tree's own Go Home branch (used when there is no dock).
    """
    branches: list[Behaviour] = [
        py_trees.composites.Sequence("Battery critical", memory=False, children=[
            check_key(ctx, "Battery critical?", "battery_critical", True),
            BatteryCritical(ctx),
        ]),
        py_trees.composites.Sequence("Lost", memory=False, children=[
            check_key(ctx, "Lost?", "lost", True),
            Relocalise(ctx),
        ]),
        battery_branch,
    ]
    if ctx.docker is None:
        return [*branches, home_branch]
    return [*branches,
            py_trees.composites.Sequence("Dock", memory=False, children=[
                check_key(ctx, "Dock?", "dock_request", None, operator.ne),
                DockAction(ctx),
            ]),
            py_trees.composites.Sequence("Go Home", memory=False, children=[
                check_key(ctx, "GoHome?", "home_request", None, operator.ne),
                RequestDock(ctx),
            ])]


def undock_branch(ctx: TreeContext) -> list[Behaviour]:
    """The Undock branch (none without a dock)."""
    if ctx.docker is None:
        return []
    return [py_trees.composites.Sequence("Undock", memory=False, children=[
        NeedsUndock(ctx), Undock(ctx)])]


def docked_branch(ctx: TreeContext) -> list[Behaviour]:
    """The Docked status branch, before Idle (none without a dock)."""
    if ctx.docker is None:
        return []
    return [py_trees.composites.Sequence("Docked", memory=False, children=[
        check_key(ctx, "Docked?", "docked", True), ShowDocked(ctx)])]
