"""The simulated base (``sim`` mode): ``/cmd_vel`` → kinematics → ``/servo_cmd`` → the world.

It implements the same :class:`~curio.drivers.base.BaseDriver` interface as the Arduino's
driver, so the application treats both alike; the simulator's wiring (``curio/sim/wiring.py``)
builds it when the ``drivers.mode`` table puts the simulator behind the base.
"""

from __future__ import annotations

import logging

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import ServoCommand, Twist
from curio.core.topics import CMD_VEL, SERVO_CMD
from curio.drivers.base import BaseDriver
from curio.drivers.kinematics import twist_to_servo_command
from curio.robot import RobotModel
from curio.sim.world import World

__all__ = ["SimBase"]

log = logging.getLogger("curio.sim")


class SimBase(BaseDriver):
    """The simulated base driver: ``/cmd_vel`` → servo command → the world.

    Applies the command timeout of the real base (``cfg.drivers.arduino.cmd_timeout_s``): a
    command older than that stops the wheels; steering keeps the last command's angles.
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock, world: World,
                 robot: RobotModel) -> None:
        self.cfg = cfg
        self.robot = robot
        self.bus = bus
        self.clock = clock
        self.world = world
        self.last_cmd: Twist | None = None
        self.last_cmd_time = -1e9
        self.timed_out = True
        self.sent = 0
        self._sub = bus.subscribe(CMD_VEL, maxsize=1)

    def _send(self, cmd: ServoCommand) -> None:
        self.world.apply_servo_command(cmd)
        self.bus.publish(SERVO_CMD, cmd)
        self.sent += 1

    def _stop_wheels(self, stamp: float) -> None:
        prev = self.bus.latest(SERVO_CMD)
        steer = prev.steer_position if prev is not None else (500, 500, 500, 500)
        self._send(ServoCommand(stamp, (0, 0, 0, 0, 0, 0), steer))

    async def run(self) -> None:
        """Forward every ``/cmd_vel`` to the servos at once."""
        async for msg in self._sub:
            now = self.clock.now()
            self.last_cmd, self.last_cmd_time, self.timed_out = msg, now, False
            try:
                cmd = twist_to_servo_command(msg.linear_mps, msg.angular_radps, self.robot,
                                             now)
            except ValueError as exc:
                log.warning("ignoring /cmd_vel: %s", exc)
                continue
            self._send(cmd)

    async def run_watchdog(self) -> None:
        """Stop the wheels when no command came for ``cmd_timeout_s``."""
        timeout = self.cfg.drivers.arduino.cmd_timeout_s
        async for t in self.clock.every(0.05, phase_s=0.004):
            if not self.timed_out and t - self.last_cmd_time > timeout:
                self.timed_out = True
                self._stop_wheels(t)

    async def halt(self) -> None:
        """Zero every wheel duty now."""
        self.timed_out = True
        self._stop_wheels(self.clock.now())

    async def close(self) -> None:
        """Stop listening."""
        self._sub.close()
