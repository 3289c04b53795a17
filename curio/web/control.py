"""What the dashboard makes the rover do: operator commands, the e-stop, the initial pose,
teleop under a lease, and the record of who did what.

One :class:`RoverControl` per dashboard, shared by the REST API and every WebSocket session.
Who is asking is an :class:`~curio.web.tokens.Identity` (a token's name and role), decided
before by :class:`curio.web.auth.Gate`; what each role may do is checked here once more, so the
REST API and the WebSocket cannot disagree.

* Commands go out on :data:`~curio.core.topics.OPERATOR` with ``source = "web:<name>"``.
  Each carries a ``request_id``; a duplicate id is acknowledged without being published again,
  also when it was received before a restart (the command journal). A command is written
  ahead: its record is committed to the event log before it is published, and so before the
  page's acknowledgement (:meth:`RoverControl.publish_command`).
  A goal off the map is refused with the map's bounds.
* The e-stop (:meth:`RoverControl.estop`) is never rate-limited and needs no parsing; it is
  published before its record is written (stopping comes first). An e-stop
  set by a named operator may be released by that operator or an admin only.
* The initial pose goes out on :data:`~curio.core.topics.INITIAL_POSE` (map, metres/radians).
* Teleop publishes :data:`~curio.core.topics.CMD_VEL_TELEOP` (source ``web:<name>``), clamped
  to the rover's limits, from **one driver at a time**: the first client to drive takes the
  lease; another client's teleop is refused (:class:`LeaseHeld`: "<name> is driving") unless it
  asks to take over. The lease lapses ``web.teleop_lease_s`` after the driver let go, or at
  once when the driver's page disconnects. A zero velocity is published when the driver goes
  silent for ``nav.safety.teleop_timeout_s`` (the deadman; the safety stage has its own
  watchdog).
* Every accepted action is published as an :class:`~curio.core.messages.Event`
  ``operator.<kind>`` with ``who``, ``role`` and ``what`` (a sentence), so every page — and
  every report — shows who did what.

Times come from the injected clock.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event, OperatorCommand, PoseWithCovariance, Twist
from curio.core.topics import CMD_VEL_TELEOP, ESTOP, EVENTS, INITIAL_POSE, MAP, OPERATOR
from curio.web.auth import refusal
from curio.web.inputs import CommandError, MapBounds, build_command, parse_pose
from curio.web.tokens import Identity

__all__ = ["LeaseHeld", "RoverControl", "action_permission", "map_bounds"]

log = logging.getLogger("curio.web.control")

# How many recent command request ids are remembered to refuse duplicates.
RECENT_REQUESTS = 512

_WORDS: dict[str, str] = {
    "go_home": "sent the rover home",
    "pause": "paused the rover",
    "resume": "resumed the rover",
    "toggle_pause": "pressed Pause/Resume",
    "cancel": "stopped the current trip",
    "help_done": "said the way is clear",
    "estop": "pressed the e-stop",
    "release_estop": "released the e-stop",
    "start_tour": "started the tour",
    "stop_tour": "stopped the tour",
}


def action_permission(action: Any) -> str:
    """The permission an operator action needs (see :data:`curio.web.tokens.PERMISSIONS`)."""
    if action in ("estop", "release_estop"):
        return "estop"
    if action in ("start_tour", "stop_tour"):
        return "tour"
    return "command"


def describe(cmd: OperatorCommand) -> str:
    """What the operator did, as the rest of a sentence after their name."""
    if cmd.action == "select_path":
        return f"chose path {cmd.path_id}"
    if cmd.action == "goto" and cmd.goal is not None:
        return f"sent the rover to ({cmd.goal.x:.2f}, {cmd.goal.y:.2f})"
    return _WORDS.get(cmd.action, cmd.action)


def map_bounds(bus: Bus) -> MapBounds | None:
    """The latest map's rectangle (None before a map has been published)."""
    grid = bus.latest(MAP)
    if grid is None:
        return None
    height, width = grid.data.shape
    return MapBounds(grid.origin, width * grid.resolution_m, height * grid.resolution_m)


class LeaseHeld(CommandError):
    """Teleop refused: another operator holds the driving lease (``holder``)."""

    def __init__(self, holder: str) -> None:
        super().__init__(f"{holder} is driving — take over?", status=409)
        self.holder = holder


@dataclass
class _Lease:
    """Who drives: the client, its operator, since when, the last message, moving or not."""

    client: int
    who: Identity
    since_s: float
    last_s: float
    moving: bool = False


class RoverControl:
    """Turns accepted operator input into bus messages; counts what it published.

    Args:
        cfg: the whole configuration (teleop limits and timeouts, the lease).
        clock: the injected clock (stamps, the deadman, the lease).
        bus: the application bus.
        paths: the path manager that command path numbers are checked against, or None.
        journal: the command journal (``seen(request_id)``): a request id received before,
            in this run or an earlier one, is not published again; None: this run only.

    Attributes:
        commands_published: operator commands published (duplicates not counted).
        teleop_published: teleop velocities published (deadman stops not counted).
        rejected_messages: dashboard messages refused (rate limits, invalid input).
        on_lease: called after the lease changed (the hub tells every page).
    """

    def __init__(self, cfg: Config, clock: Clock, bus: Bus, paths: Any = None,
                 journal: Any = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = bus
        self.paths = paths
        self.journal = journal
        self._recent_requests: OrderedDict[str, float] = OrderedDict()
        self._lease: _Lease | None = None
        self.commands_published = 0
        self.teleop_published = 0
        self.rejected_messages = 0
        self.on_lease: Callable[[], None] | None = None

    # --- who did what -------------------------------------------------------------------------

    def activity(self, who: Identity, kind: str, what: str, **detail: Any) -> None:
        """Publish ``operator.<kind>``: ``who`` did ``what`` (every page shows it)."""
        self.bus.publish(EVENTS, Event(self.clock.now(), f"operator.{kind}", {
            "who": who.name, "role": who.role, "what": what, **detail}))

    # --- commands, the e-stop and the initial pose --------------------------------------------

    async def command(self, body: dict[str, Any],
                      who: Identity) -> tuple[OperatorCommand, bool]:
        """Validate ``{action, path_id?, goal?, request_id?}`` from ``who`` and publish it.

        Returns:
            The command and whether it was published (False: a duplicate request id).

        Raises:
            CommandError: the command is invalid, off the map, or not ``who``'s to give (403).
        """
        action = body.get("action")
        permission = action_permission(action)
        if not who.may(permission):
            raise CommandError(refusal(who, permission), status=403)
        if action == "release_estop":
            self._check_release(who)
        cmd = build_command(body, self.clock, self.paths, who.source, map_bounds(self.bus))
        return cmd, await self.publish_command(cmd, who)

    async def estop(self, who: Identity, request_id: str = "") -> OperatorCommand:
        """Engage the e-stop now (never limited, nothing to parse), then write its record."""
        cmd = OperatorCommand(self.clock.now(), "estop", source=who.source,
                              request_id=request_id)
        await self.publish_command(cmd, who, write_first=False)
        return cmd

    def _check_release(self, who: Identity) -> None:
        """An e-stop set by a named operator: only that operator or an admin releases it."""
        state = self.bus.latest(ESTOP)
        if state is None or not state.engaged or who.may("release_any_estop"):
            return
        channel, _, owner = state.source.partition(":")
        if channel in ("web", "kiosk") and owner and owner != who.name:
            raise CommandError(f"the e-stop was set by {owner}; only {owner} or an admin may "
                               "release it", status=403)

    async def publish_command(self, cmd: OperatorCommand, who: Identity | None = None, *,
                              write_first: bool = True) -> bool:
        """Publish ``cmd`` on OPERATOR unless its request id was seen; return True if published.

        With the journal, the command's record is committed first (``write_first``: for the
        e-stop it is published first, then written), so that whoever is told "published"
        can ask the next run about it after a ``kill -9``."""
        if cmd.request_id:
            if cmd.request_id in self._recent_requests or (
                    self.journal is not None and self.journal.seen(cmd.request_id)):
                return False
            self._recent_requests[cmd.request_id] = cmd.stamp
            while len(self._recent_requests) > RECENT_REQUESTS:
                self._recent_requests.popitem(last=False)
        if self.journal is not None and write_first:
            await self.journal.write_ahead(cmd)
        self.bus.publish(OPERATOR, cmd)
        if self.journal is not None and not write_first:
            await self.journal.write_ahead(cmd)
        self.commands_published += 1
        if who is not None:
            detail: dict[str, Any] = {"action": cmd.action, "request_id": cmd.request_id}
            if cmd.goal is not None:
                detail["goal"] = [round(cmd.goal.x, 3), round(cmd.goal.y, 3)]
            if cmd.path_id is not None:
                detail["path_id"] = cmd.path_id
            self.activity(who, "command", describe(cmd), **detail)
        return True

    def initial_pose(self, body: dict[str, Any], who: Identity,
                     spread: tuple[float, float] | None = None) -> Pose2D:
        """Validate ``{x_m, y_m, yaw_rad?}`` (map) and publish it as the initial pose, with
        ``spread`` (standard deviations: metres in x and y, radians in yaw) or the default
        covariance.

        Raises:
            CommandError: a coordinate is missing, not a finite number, or off the map.
        """
        pose = parse_pose(body)
        bounds = map_bounds(self.bus)
        if bounds is not None:
            bounds.require(pose.x, pose.y, "the position")
        if spread is None:
            msg = PoseWithCovariance(self.clock.now(), pose)
        else:
            sxy, syaw = spread[0] ** 2, spread[1] ** 2
            msg = PoseWithCovariance(self.clock.now(), pose, (sxy, 0.0, 0.0, 0.0, sxy, 0.0,
                                                              0.0, 0.0, syaw))
        self.bus.publish(INITIAL_POSE, msg)
        self.activity(who, "initial_pose",
                      f"set the rover's position to ({pose.x:.2f}, {pose.y:.2f}), "
                      f"facing {math.degrees(pose.yaw):.0f}°"
                      + (f" (± {spread[0]:.2f} m)" if spread is not None else ""),
                      pose=[round(pose.x, 3), round(pose.y, 3), round(pose.yaw, 4)])
        return pose

    # --- teleop, its lease and its deadman ----------------------------------------------------

    def teleop_limits(self) -> tuple[float, float]:
        """Teleop limits: (linear m/s, angular rad/s)."""
        robot, safety = self.cfg.robot, self.cfg.nav.safety
        return (min(robot.max_wheel_speed_mps, safety.max_speed_mps),
                min(robot.max_angular_radps, safety.max_angular_radps))

    def lease_json(self) -> dict[str, Any]:
        """Who holds the driving lease: ``{holder, client, driving, since}`` (None when free)."""
        lease = self._lease
        if lease is None:
            return {"holder": None, "client": None, "driving": False, "since": None}
        return {"holder": lease.who.name, "client": lease.client, "driving": lease.moving,
                "since": lease.since_s}

    def _lease_fresh(self, lease: _Lease, now: float) -> bool:
        return lease.moving or now - lease.last_s <= self.cfg.web.teleop_lease_s

    def _lease_changed(self) -> None:
        if self.on_lease is not None:
            self.on_lease()

    def teleop(self, client_id: int, who: Identity, linear_mps: float, angular_radps: float,
               take_over: bool = False) -> tuple[float, float]:
        """Publish a teleop velocity from client ``client_id`` (clamped); return it.

        A ``take_over`` takes the lease even with a zero velocity (which stops the rover until
        the new driver moves the stick).

        Raises:
            LeaseHeld: another client drives and ``take_over`` is not set.
        """
        limits = self.teleop_limits()
        lin = max(-limits[0], min(limits[0], linear_mps))
        ang = max(-limits[1], min(limits[1], angular_radps))
        moving = lin != 0.0 or ang != 0.0
        now = self.clock.now()
        lease = self._lease
        changed = False
        if lease is None or lease.client != client_id:
            fresh = lease is not None and self._lease_fresh(lease, now)
            if lease is not None and fresh and not take_over:
                raise LeaseHeld(lease.who.name)
            if not moving and not take_over:
                return 0.0, 0.0  # letting go of a stick one does not hold: nothing to do
            what = (f"took over driving from {lease.who.name}" if lease is not None and fresh
                    else "started driving by hand")
            self._lease = lease = _Lease(client_id, who, now, now)
            self.activity(who, "teleop", what)
            changed = True
        changed = changed or lease.moving != moving
        lease.last_s = now
        lease.moving = moving
        self.bus.publish(CMD_VEL_TELEOP, Twist(now, lin, ang, source=who.source))
        self.teleop_published += 1
        if changed:
            self._lease_changed()
        return lin, ang

    def release_teleop(self, client_id: int, reason: str) -> None:
        """Client ``client_id`` is gone: if it was driving, stop the rover and free the lease."""
        lease = self._lease
        if lease is not None and lease.client == client_id:
            self._stop_teleop(reason)
            self._lease = None
            self._lease_changed()

    def _stop_teleop(self, reason: str) -> None:
        lease = self._lease
        if lease is not None and lease.moving:
            self.bus.publish(CMD_VEL_TELEOP, Twist(self.clock.now(), 0.0, 0.0,
                                                   source=lease.who.source))
            log.info("teleop stopped: %s", reason)
            lease.moving = False

    async def watch_teleop(self) -> None:
        """The deadman and the lease's end (until cancelled): stop a moving rover whose driver
        went silent; free the lease ``web.teleop_lease_s`` after the driver let go."""
        timeout_s = self.cfg.nav.safety.teleop_timeout_s
        period_s = min(0.1, timeout_s / 4)
        async for now in self.clock.every(period_s, phase_s=period_s):
            lease = self._lease
            if lease is None:
                continue
            if lease.moving and now - lease.last_s > timeout_s:
                self._stop_teleop(f"no teleop message for {timeout_s:.1f} s")
                self._lease_changed()
            elif not lease.moving and now - lease.last_s > self.cfg.web.teleop_lease_s:
                self._lease = None
                self._lease_changed()
