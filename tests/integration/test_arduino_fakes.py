"""A tiny stand-in for the simulator world, for the Arduino emulator tests."""

from __future__ import annotations

from curio.core.messages import ServoCommand
from curio.drivers.arduino.lx16a import reading_from_count

COUNTS_PER_S_PER_DUTY = 1.5  # duty 1000 → one turn (1500 counts) per second


class FakeWorld:
    """Integrates wheel counts from the commanded duties; reports LX-16A readings."""

    def __init__(self, vin_v: float = 7.4) -> None:
        self.vin_v = vin_v
        self.duties: tuple[int, ...] = (0,) * 6
        self.steer: tuple[int, ...] = (500,) * 4
        self.counts = [100.0] * 6
        self.commands = 0
        self._last_s: float | None = None

    def apply_servo_command(self, cmd: ServoCommand) -> None:
        if self._last_s is not None:
            dt = max(0.0, cmd.stamp - self._last_s)
            for i, d in enumerate(self.duties):
                self.counts[i] += d * COUNTS_PER_S_PER_DUTY * dt
        self._last_s = cmd.stamp
        self.duties = tuple(cmd.wheel_duty)
        self.steer = tuple(cmd.steer_position)
        self.commands += 1

    def wheel_positions(self) -> list[int]:
        return [reading_from_count(c) for c in self.counts]

    def battery_voltage(self) -> float:
        return self.vin_v
