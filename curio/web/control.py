"""What the dashboard makes the rover do: operator commands, the initial pose, teleop.

One :class:`RoverControl` per dashboard, shared by the REST API and every WebSocket session
(who *may* control is decided before, by :class:`curio.web.auth.ControlGate`):

* Commands go out on :data:`~curio.core.topics.OPERATOR`. Commands are never queued or
  replayed: each carries a ``request_id`` and a duplicate id is acknowledged without being
  published again.
* The initial pose goes out on :data:`~curio.core.topics.INITIAL_POSE` (map, metres/radians).
* Teleop publishes :data:`~curio.core.topics.CMD_VEL_TELEOP` (source ``web``), clamped to the
  rover's limits. The rover has one teleop driver at a time (the client that sent the latest
  teleop message); a zero velocity is published when that client disconnects or goes silent
  for ``cfg.nav.safety.teleop_timeout_s`` (the deadman; the safety stage also has its own
  watchdog).

Times come from the injected clock.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorCommand, PoseWithCovariance, Twist
from curio.core.topics import CMD_VEL_TELEOP, INITIAL_POSE, OPERATOR
from curio.web.inputs import build_command, parse_pose

__all__ = ["RoverControl"]

log = logging.getLogger("curio.web.control")

# How many recent command request ids are remembered to refuse duplicates.
RECENT_REQUESTS = 512


class RoverControl:
    """Turns accepted operator input into bus messages; counts what it published.

    Args:
        cfg: the whole configuration (teleop limits and timeout).
        clock: the injected clock (stamps, the deadman).
        bus: the application bus.
        paths: the path manager that command path numbers are checked against, or None.

    Attributes:
        commands_published: operator commands published (duplicates not counted).
        teleop_published: teleop velocities published (deadman stops not counted).
        rejected_messages: dashboard messages refused (rate limits, invalid input).
    """

    def __init__(self, cfg: Config, clock: Clock, bus: Bus, paths: Any = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = bus
        self.paths = paths
        self._recent_requests: OrderedDict[str, float] = OrderedDict()
        self._teleop_client: int | None = None
        self._teleop_last_s = -math.inf
        self._teleop_moving = False
        self.commands_published = 0
        self.teleop_published = 0
        self.rejected_messages = 0

    # --- commands and the initial pose --------------------------------------------------------

    def command(self, body: dict[str, Any],
                source: str = "web") -> tuple[OperatorCommand, bool]:
        """Validate ``{action, path_id?, goal?, request_id?}`` and publish it.

        Returns:
            The command and whether it was published (False: a duplicate request id).

        Raises:
            CommandError: the command is invalid (the message says why).
        """
        cmd = build_command(body, self.clock, self.paths, source)
        return cmd, self.publish_command(cmd)

    def publish_command(self, cmd: OperatorCommand) -> bool:
        """Publish ``cmd`` on OPERATOR unless its request id was seen; return True if published."""
        if cmd.request_id:
            if cmd.request_id in self._recent_requests:
                return False
            self._recent_requests[cmd.request_id] = cmd.stamp
            while len(self._recent_requests) > RECENT_REQUESTS:
                self._recent_requests.popitem(last=False)
        self.bus.publish(OPERATOR, cmd)
        self.commands_published += 1
        return True

    def initial_pose(self, body: dict[str, Any]) -> Pose2D:
        """Validate ``{x_m, y_m, yaw_rad?}`` (map) and publish it as the initial pose.

        Raises:
            CommandError: a coordinate is missing or not a finite number.
        """
        pose = parse_pose(body)
        self.bus.publish(INITIAL_POSE, PoseWithCovariance(self.clock.now(), pose))
        return pose

    # --- teleop and its deadman ---------------------------------------------------------------

    def teleop_limits(self) -> tuple[float, float]:
        """Teleop limits: (linear m/s, angular rad/s)."""
        robot, safety = self.cfg.robot, self.cfg.nav.safety
        return (min(robot.max_wheel_speed_mps, safety.max_speed_mps),
                min(robot.max_angular_radps, safety.max_angular_radps))

    def teleop(self, client_id: int, linear_mps: float,
               angular_radps: float) -> tuple[float, float]:
        """Publish a teleop velocity from client ``client_id`` (clamped); return it."""
        limits = self.teleop_limits()
        lin = max(-limits[0], min(limits[0], linear_mps))
        ang = max(-limits[1], min(limits[1], angular_radps))
        now = self.clock.now()
        self._teleop_client = client_id
        self._teleop_last_s = now
        self._teleop_moving = lin != 0.0 or ang != 0.0
        self.bus.publish(CMD_VEL_TELEOP, Twist(now, lin, ang, source="web"))
        self.teleop_published += 1
        return lin, ang

    def release_teleop(self, client_id: int, reason: str) -> None:
        """Client ``client_id`` is gone: if it was driving, stop the rover."""
        if self._teleop_client == client_id:
            self._stop_teleop(reason)

    def _stop_teleop(self, reason: str) -> None:
        if self._teleop_moving or self._teleop_client is not None:
            self.bus.publish(CMD_VEL_TELEOP, Twist(self.clock.now(), 0.0, 0.0, source="web"))
            log.info("teleop stopped: %s", reason)
        self._teleop_moving = False
        self._teleop_client = None

    async def watch_teleop(self) -> None:
        """The deadman: stop a moving rover whose driver went silent (until cancelled)."""
        timeout_s = self.cfg.nav.safety.teleop_timeout_s
        period_s = min(0.1, timeout_s / 4)
        async for now in self.clock.every(period_s, phase_s=period_s):
            if self._teleop_moving and now - self._teleop_last_s > timeout_s:
                self._stop_teleop(f"no teleop message for {timeout_s:.1f} s")
