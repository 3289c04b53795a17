"""Driver wiring: odometry in every mode; device drivers (and emulators) when not in sim mode.

* every mode: :class:`~curio.drivers.odometry.WheelOdometry` (``/wheels`` → ``/wheel_odom``);
* ``sim`` mode: the simulator publishes the sensors and its ``SimBase`` is the base
  (``curio/sim/wiring.py``);
* ``emulated`` and ``real``: the same three real driver classes,
  :class:`~curio.drivers.arduino.driver.ArduinoBase` (the base; its ``halt`` is a halt hook),
  :class:`~curio.drivers.rplidar.driver.RplidarDriver` and
  :class:`~curio.drivers.bno055.driver.Bno055Driver`.

``real``: they open ``drivers.arduino.port``, ``drivers.lidar.port`` and
``/dev/i2c-<drivers.imu.i2c_bus>``; smbus2 calls run in a worker thread.

``emulated``: the byte-exact device emulators are built first, fed by the simulator's world
(which then publishes no sensor messages itself): the Arduino
(:class:`~curio.drivers.arduino.emulator.ArduinoEmulator`) and the RPLidar
(:class:`~curio.drivers.rplidar.emulator.RplidarEmulator`) on pseudo-terminals, the BNO055 on a
fake I2C bus (:class:`~curio.drivers.bno055.emulator.Bno055Emulator`, called inline since it is
in memory). The drivers are pointed at the emulators' pty paths and at the fake bus. Each
emulator's part is registered before its driver's, so its pty exists when the driver opens it.

Under systemd (``NOTIFY_SOCKET`` set, ``deploy/curio.service``) a
:class:`~curio.drivers.health.SystemdNotifier` part reports readiness, feeds the watchdog and
shows the drivers' health in ``systemctl status curio``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import Imu, LaserScan
from curio.core.parts import Part, Parts
from curio.drivers.arduino.driver import ArduinoBase
from curio.drivers.arduino.emulator import EmulatorWorld
from curio.drivers.base import BaseDriver
from curio.drivers.bno055.driver import Bno055Driver, SMBusLike
from curio.drivers.health import SystemdNotifier
from curio.drivers.odometry import WheelOdometry
from curio.drivers.rplidar.driver import RplidarDriver
from curio.robot import RobotModel

__all__ = ["Drivers", "SimulatedWorld", "build_drivers"]


class SimulatedWorld(EmulatorWorld, Protocol):
    """What the device emulators read from the simulator (emulated mode)."""

    def cast_scan(self, stamp: float) -> LaserScan:
        """One lidar revolution from the true pose, ``laser`` frame."""
        ...

    def imu_sample(self, stamp: float) -> Imu:
        """One BNO055 reading in ``imu_link``."""
        ...


@dataclass
class Drivers:
    """The drivers subsystem's objects (None where the mode has none)."""

    odometry: WheelOdometry
    base: BaseDriver | None = None
    lidar: RplidarDriver | None = None
    imu: Bno055Driver | None = None
    emulators: list[Any] = field(default_factory=list)


def build_drivers(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel, *,
                  world: SimulatedWorld | None = None,
                  sim_base: BaseDriver | None = None) -> Drivers:
    """Construct the drivers for ``drivers.mode`` and register them on ``parts``.

    Args:
        world: the simulator's world (``sim`` and ``emulated`` modes): feeds the emulators.
        sim_base: the simulator's base (``sim`` mode): it is the base then.
    """
    odometry = WheelOdometry(robot, bus, clock)
    parts.add(Part("odometry", run=odometry.run, close=odometry.close))
    drivers = Drivers(odometry, base=sim_base)
    if cfg.drivers.mode != "sim":
        _device_drivers(cfg, bus, clock, parts, robot, world, drivers)
    return drivers


def _device_drivers(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
                    world: SimulatedWorld | None, out: Drivers) -> None:
    """The Arduino, RPLidar and BNO055 drivers (and, in emulated mode, their emulators)."""
    dcfg = cfg.drivers
    arduino_port = dcfg.arduino.port
    lidar_port = dcfg.lidar.port
    calibration_file = dcfg.imu.calibration_file
    lidar_motor: Callable[[bool], None] | None = None
    open_bus: Callable[[], SMBusLike] | None = None
    offload = True
    pair: list[Callable[[], None]] = []
    if dcfg.mode == "emulated":
        if world is None:
            raise RuntimeError("drivers.mode = 'emulated' needs the simulator world "
                               "(curio/sim/wiring.py builds it in sim and emulated modes)")
        from curio.drivers.arduino.emulator import ArduinoEmulator
        from curio.drivers.bno055.emulator import Bno055Emulator
        from curio.drivers.rplidar.emulator import RplidarEmulator

        seed = cfg.sim.seed
        arduino_emu = ArduinoEmulator(world, clock, seed=seed)
        arduino_emu.open()
        lidar_emu = RplidarEmulator(world.cast_scan, clock, rate_hz=cfg.sim.lidar_rate_hz,
                                    seed=seed + 1, angle_offset_rad=dcfg.lidar.angle_offset_rad)
        imu_bus = Bno055Emulator(world.imu_sample, clock.now, address=dcfg.imu.address,
                                seed=seed + 2)
        out.emulators.extend([arduino_emu, lidar_emu, imu_bus])
        parts.add(Part("arduino-emulator", run=arduino_emu.run, close=arduino_emu.aclose))
        parts.add(Part("lidar-emulator", run=lidar_emu.run, close=lidar_emu.close))
        arduino_port = arduino_emu.port_path
        lidar_port = lidar_emu.path
        lidar_motor = lidar_emu.set_motor
        open_bus = imu_bus.reopen
        offload = False
        # The emulated chip's calibration must never be restored into the real one.
        calibration_file = "emulated-" + calibration_file
        # Hold the simulated clock while pty bytes are in flight (exact byte accounting).
        pair = [lambda: arduino_emu.pair(base), lambda: lidar_emu.pair(lidar)]
    base = ArduinoBase(dcfg.arduino, robot, bus, clock, port=arduino_port)
    lidar = RplidarDriver(dcfg.lidar, clock, bus, port=lidar_port, motor=lidar_motor)
    imu = Bno055Driver(dcfg.imu, clock, bus, calibration_path=cfg.data_path(calibration_file),
                       open_bus=open_bus, offload=offload)
    out.base, out.lidar, out.imu = base, lidar, imu
    for connect in pair:
        connect()
    parts.add(Part("arduino", run=base.run, close=base.close))
    parts.add_halt_hook(base.halt)
    parts.add(Part("lidar", run=lidar.run, close=lidar.close))
    parts.add(Part("imu", run=imu.run, close=imu.close))
    notifier = SystemdNotifier(clock, bus, os.environ)
    if notifier.enabled:  # started by systemd (deploy/curio.service): READY=1 and watchdog
        parts.add(Part("systemd-notify", run=notifier.run))


