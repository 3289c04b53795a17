"""``drivers.mode``: which implementation stands behind each device, in one table.

    drivers.mode  base                      lidar                     imu
    sim           simulator (SimBase)       simulator (/scan)         simulator (/imu)
    emulated      emulator: ArduinoBase     emulator: RplidarDriver   emulator: Bno055Driver
                  on ArduinoEmulator        on RplidarEmulator        on Bno055Emulator
    real          hardware: ArduinoBase     hardware: RplidarDriver   hardware: Bno055Driver

A cell says where that device's data comes from (a fake is chosen exactly like real hardware,
as in LeRobot's config-type registry; each device has a hardware and a simulation side, as in
RoSys):

* ``hardware``: the device's driver on the device (serial port, I2C bus);
* ``emulator``: the same driver on the device's byte-exact emulator (a pseudo-terminal, a fake
  I2C bus), which the simulator's world feeds;
* ``simulator``: no driver; the simulator publishes the device's messages itself (the base is
  :class:`~curio.sim.base.SimBase`).

``curio/drivers/wiring.py`` builds the hardware and emulator cells from its table of device
pairs (driver, emulator); ``curio/sim/wiring.py`` builds the world whenever a cell needs it and
the simulator cells. Code that depends on the mode asks the row (``world``, ``emulated``,
``simulated``, ``source(role)``) rather than comparing ``drivers.mode`` with a name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from curio.core.config import Config

__all__ = ["MODES", "DriverMode", "Role", "Source", "driver_mode"]

Source = Literal["hardware", "emulator", "simulator"]
Role = Literal["base", "lidar", "imu"]


@dataclass(frozen=True)
class DriverMode:
    """One row of the table: the source of each device."""

    name: str
    base: Source
    lidar: Source
    imu: Source

    def source(self, role: Role) -> Source:
        """Where the device in ``role`` gets its data."""
        return {"base": self.base, "lidar": self.lidar, "imu": self.imu}[role]

    @property
    def sources(self) -> tuple[Source, Source, Source]:
        """The base's, the lidar's and the IMU's source."""
        return self.base, self.lidar, self.imu

    @property
    def world(self) -> bool:
        """The simulator's world runs (it feeds an emulator or stands in for a device), so the
        application may run on simulated time."""
        return any(source != "hardware" for source in self.sources)

    @property
    def emulated(self) -> bool:
        """Some device is emulated (bytes cross pseudo-terminals)."""
        return "emulator" in self.sources

    @property
    def simulated(self) -> bool:
        """Every device is the simulator's (no driver runs)."""
        return all(source == "simulator" for source in self.sources)


MODES: dict[str, DriverMode] = {
    mode.name: mode for mode in (
        DriverMode("sim", base="simulator", lidar="simulator", imu="simulator"),
        DriverMode("emulated", base="emulator", lidar="emulator", imu="emulator"),
        DriverMode("real", base="hardware", lidar="hardware", imu="hardware"),
    )
}


def driver_mode(cfg: Config) -> DriverMode:
    """The row ``cfg.drivers.mode`` names."""
    return MODES[cfg.drivers.mode]
