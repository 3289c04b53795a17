"""Driver wiring: odometry in every mode; each device's driver on its hardware or its emulator.

* every mode: :class:`~curio.drivers.odometry.WheelOdometry` (``/wheels`` → ``/wheel_odom``);
* per device, what the ``drivers.mode`` table (:mod:`curio.drivers.modes`) says:

  - ``hardware``: the device's driver on the device: :class:`~curio.drivers.arduino.driver.
    ArduinoBase` on ``drivers.arduino.port`` (the base; its ``halt`` is a halt hook),
    :class:`~curio.drivers.rplidar.driver.RplidarDriver` on ``drivers.lidar.port``,
    :class:`~curio.drivers.bno055.driver.Bno055Driver` on ``/dev/i2c-<drivers.imu.i2c_bus>``
    (smbus2 calls in a worker thread);
  - ``emulator``: the same driver on the device's byte-exact emulator, fed by the simulator's
    world: :class:`~curio.drivers.arduino.emulator.ArduinoEmulator` and
    :class:`~curio.drivers.rplidar.emulator.RplidarEmulator` on pseudo-terminals (paired with
    their drivers, so a fast simulated clock waits for pty delivery),
    :class:`~curio.drivers.bno055.emulator.Bno055Emulator` as a fake I2C bus called inline (it
    is in memory; its calibration file is kept apart from the real chip's);
  - ``simulator``: nothing here; the simulator publishes the device's messages and its
    ``SimBase`` is the base (``curio/sim/wiring.py``).

:data:`BASE`, :data:`LIDAR` and :data:`IMU` pair each device's driver with its emulator
(RoSys's hardware/simulation pairs); ``curio emulate`` serves the emulators from the same rows.
The emulators' parts are registered (and so start) before the drivers', so a pty exists when
its driver opens it.

Under systemd (``NOTIFY_SOCKET`` set, ``deploy/curio.service``) a
:class:`~curio.drivers.health.SystemdNotifier` part reports readiness, feeds the watchdog and
shows the drivers' health in ``systemctl status curio``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Generic, Protocol, TypeVar

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.parts import Part, Parts
from curio.drivers.arduino.driver import ArduinoBase
from curio.drivers.arduino.emulator import ArduinoEmulator, EmulatorWorld
from curio.drivers.base import BaseDriver
from curio.drivers.bno055.driver import Bno055Driver
from curio.drivers.bno055.emulator import Bno055Emulator, ImuWorld
from curio.drivers.health import SystemdNotifier
from curio.drivers.modes import DriverMode, Role, Source, driver_mode
from curio.drivers.odometry import WheelOdometry
from curio.drivers.rplidar.driver import RplidarDriver
from curio.drivers.rplidar.emulator import RplidarEmulator, ScanWorld
from curio.robot import RobotModel

__all__ = [
    "BASE", "IMU", "LIDAR", "Device", "DeviceEmulator", "Drivers", "SimulatedWorld",
    "build_drivers",
]


class SimulatedWorld(EmulatorWorld, ScanWorld, ImuWorld, Protocol):
    """What the device emulators read from the simulator's world (all three together)."""


class DeviceEmulator(Protocol):
    """What the table needs from an emulator."""

    @property
    def path(self) -> str | None:
        """The device node a client opens (None: not a serial device)."""
        ...

    def open(self) -> object:
        """Create the device node (a pseudo-terminal), if any."""
        ...

    def parts(self) -> list[Part]:
        """What runs it (nothing for an in-memory device)."""
        ...


E = TypeVar("E", bound=DeviceEmulator)
E_co = TypeVar("E_co", bound=DeviceEmulator, covariant=True)
D = TypeVar("D")


@dataclass(frozen=True)
class DeviceContext:
    """What every driver is built from."""

    cfg: Config
    bus: Bus
    clock: Clock
    robot: RobotModel


class EmulatorFactory(Protocol[E_co]):
    """An emulator's ``for_world`` class method."""

    def __call__(self, world: SimulatedWorld, clock: Clock, cfg: Config, seed: int,
                 link: Path | None = None) -> E_co:
        """The emulator on ``world``; ``link``: the device path to serve, if it has one."""
        ...


@dataclass(frozen=True)
class Device(Generic[E, D]):
    """One device: its driver and its emulator.

    Attributes:
        name: the device (its folder; ``curio emulate`` takes it).
        role: its column in the ``drivers.mode`` table.
        emulator: builds the emulator on the simulator's world.
        driver: builds the driver, on the hardware (None) or on the emulator.
        seed_offset: added to ``sim.seed`` for the emulator's randomness.
        serves: what ``curio emulate`` calls it (None: not served on a pseudo-terminal).
    """

    name: str
    role: Role
    emulator: EmulatorFactory[E]
    driver: Callable[[DeviceContext, E | None], D]
    seed_offset: int
    serves: str | None = None

    def source(self, mode: DriverMode) -> Source:
        """Where this device's data comes from in ``mode``."""
        return mode.source(self.role)


def _arduino(ctx: DeviceContext, emulator: ArduinoEmulator | None) -> ArduinoBase:
    base = ArduinoBase(ctx.cfg.drivers.arduino, ctx.robot, ctx.bus, ctx.clock,
                       port=emulator.path if emulator else None)
    if emulator is not None:
        emulator.pair(base)  # hold the simulated clock while pty bytes are in flight
    return base


def _rplidar(ctx: DeviceContext, emulator: RplidarEmulator | None) -> RplidarDriver:
    if emulator is None:
        return RplidarDriver(ctx.cfg.drivers.lidar, ctx.clock, ctx.bus)
    lidar = RplidarDriver(ctx.cfg.drivers.lidar, ctx.clock, ctx.bus, port=emulator.path,
                          motor=emulator.set_motor)  # a pty has no DTR line for the motor
    emulator.pair(lidar)
    return lidar


def _bno055(ctx: DeviceContext, emulator: Bno055Emulator | None) -> Bno055Driver:
    icfg = ctx.cfg.drivers.imu
    if emulator is None:
        return Bno055Driver(icfg, ctx.clock, ctx.bus,
                            calibration_path=ctx.cfg.data_path(icfg.calibration_file))
    # The emulated chip's calibration must never be restored into the real one; the in-memory
    # bus is called inline (deterministic on simulated time).
    return Bno055Driver(icfg, ctx.clock, ctx.bus,
                        calibration_path=ctx.cfg.data_path("emulated-" + icfg.calibration_file),
                        open_bus=emulator.reopen, offload=False)


#: The devices: each one's emulator and driver (built in this order).
BASE = Device("arduino", "base", ArduinoEmulator.for_world, _arduino, 0,
              serves="Arduino Mega base controller (115200 baud)")
LIDAR = Device("rplidar", "lidar", RplidarEmulator.for_world, _rplidar, 1,
               serves="RPLidar A1M8 (115200 baud; motor always on: no DTR on a pty)")
IMU = Device("bno055", "imu", Bno055Emulator.for_world, _bno055, 2)


@dataclass
class Drivers:
    """The drivers subsystem's objects (None where the mode has none)."""

    odometry: WheelOdometry
    base: BaseDriver | None = None
    lidar: RplidarDriver | None = None
    imu: Bno055Driver | None = None
    emulators: list[DeviceEmulator] = field(default_factory=list)


def build_drivers(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel, *,
                  world: SimulatedWorld | None = None,
                  sim_base: BaseDriver | None = None) -> Drivers:
    """Construct the drivers for ``drivers.mode`` and register them on ``parts``.

    Args:
        world: the simulator's world (when a device is emulated or simulated).
        sim_base: the simulator's base (when the base is simulated): it is the base then.
    """
    odometry = WheelOdometry(robot, bus, clock)
    parts.add(Part("odometry", run=odometry.run, close=odometry.close))
    drivers = Drivers(odometry, base=sim_base)
    mode = driver_mode(cfg)
    if not mode.simulated:
        _device_drivers(DeviceContext(cfg, bus, clock, robot), mode, parts, world, drivers)
    return drivers


def _emulator(device: Device[E, D], mode: DriverMode, ctx: DeviceContext,
              world: SimulatedWorld | None) -> E | None:
    """The device's emulator when ``mode`` emulates it."""
    if device.source(mode) != "emulator":
        return None
    if world is None:
        raise RuntimeError(f"drivers.mode = '{mode.name}' needs the simulator world "
                           "(curio/sim/wiring.py builds it when a device is emulated)")
    return device.emulator(world, ctx.clock, ctx.cfg, ctx.cfg.sim.seed + device.seed_offset)


def _driver(device: Device[E, D], mode: DriverMode, ctx: DeviceContext,
            emulator: E | None) -> D | None:
    """The device's driver (on its emulator, if it has one), unless ``mode`` simulates it."""
    return None if device.source(mode) == "simulator" else device.driver(ctx, emulator)


def _device_drivers(ctx: DeviceContext, mode: DriverMode, parts: Parts,
                    world: SimulatedWorld | None, out: Drivers) -> None:
    """The drivers (and emulators) of the devices ``mode`` does not simulate."""
    arduino = _emulator(BASE, mode, ctx, world)
    lidar = _emulator(LIDAR, mode, ctx, world)
    imu = _emulator(IMU, mode, ctx, world)
    for emulator in (arduino, lidar, imu):
        if emulator is not None:
            out.emulators.append(emulator)
            for part in emulator.parts():
                parts.add(part)
    base = _driver(BASE, mode, ctx, arduino)
    out.lidar = _driver(LIDAR, mode, ctx, lidar)
    out.imu = _driver(IMU, mode, ctx, imu)
    if base is not None:
        out.base = base
        parts.add(Part("arduino", run=base.run, close=base.close))
        parts.add_halt_hook(base.halt)
    for driver in (out.lidar, out.imu):
        if driver is not None:
            parts.add(Part(driver.name, run=driver.run, close=driver.close))
    notifier = SystemdNotifier(ctx.clock, ctx.bus, os.environ)
    if notifier.enabled:  # started by systemd (deploy/curio.service): READY=1 and watchdog
        parts.add(Part("systemd-notify", run=notifier.run))
