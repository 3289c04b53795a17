"""Device drivers for ``emulated`` and ``real`` modes (called by ``curio/drivers/wiring.py``).

``build_device_drivers(app)`` builds the same three real driver classes in both modes:

* :class:`~curio.drivers.arduino.driver.ArduinoBase` (``app.base``; its ``halt`` is a halt hook),
* :class:`~curio.drivers.rplidar.driver.RplidarDriver` (``app.lidar``),
* :class:`~curio.drivers.bno055.driver.Bno055Driver` (``app.imu``).

``real``: they open ``drivers.arduino.port``, ``drivers.lidar.port`` and
``/dev/i2c-<drivers.imu.i2c_bus>``; smbus2 calls run in a worker thread.

``emulated``: the byte-exact device emulators are built first, fed by ``app.world`` (the
simulator, which then publishes no sensor messages itself) and listed in ``app.emulators``:
the Arduino (:class:`~curio.drivers.arduino.emulator.ArduinoEmulator`) and the RPLidar
(:class:`~curio.drivers.rplidar.emulator.RplidarEmulator`) on pseudo-terminals, the BNO055 on a
fake I2C bus (:class:`~curio.drivers.bno055.fake_bus.FakeBno055Bus`, called inline since it is
in memory). The drivers are pointed at the emulators' pty paths and at the fake bus. Each
emulator's part is registered before its driver's, so its pty exists when the driver opens it.

Under systemd (``NOTIFY_SOCKET`` set, ``deploy/curio.service``) a
:class:`~curio.drivers.health.SystemdNotifier` part reports readiness, feeds the watchdog and
shows the drivers' health in ``systemctl status curio``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

from curio.drivers.arduino.driver import ArduinoBase
from curio.drivers.bno055.driver import Bno055Driver, SMBusLike
from curio.drivers.health import SystemdNotifier
from curio.drivers.rplidar.driver import RplidarDriver

if TYPE_CHECKING:
    from collections.abc import Callable

    from curio.app import App

__all__ = ["build_device_drivers"]


def build_device_drivers(app: App) -> None:
    """Build the device drivers (and, in emulated mode, their emulators) on ``app``."""
    from curio.app import Part

    cfg = app.cfg
    dcfg = cfg.drivers
    arduino_port = dcfg.arduino.port
    lidar_port = dcfg.lidar.port
    calibration_file = dcfg.imu.calibration_file
    lidar_motor: Callable[[bool], None] | None = None
    open_bus: Callable[[], SMBusLike] | None = None
    offload = True
    if dcfg.mode == "emulated":
        if app.world is None:
            raise RuntimeError(
                "drivers.mode = 'emulated' needs the simulator world (curio/sim/wiring.py "
                "builds it in sim and emulated modes)"
            )
        from curio.drivers.arduino.emulator import ArduinoEmulator
        from curio.drivers.bno055.fake_bus import FakeBno055Bus
        from curio.drivers.rplidar.emulator import RplidarEmulator

        world: Any = app.world
        seed = cfg.sim.seed
        arduino_emu = ArduinoEmulator(world, app.clock, seed=seed)
        arduino_emu.open()
        lidar_emu = RplidarEmulator(
            world.cast_scan,
            app.clock,
            rate_hz=cfg.sim.lidar_rate_hz,
            seed=seed + 1,
            angle_offset_rad=dcfg.lidar.angle_offset_rad,
        )
        imu_bus = FakeBno055Bus(
            world.imu_sample, app.clock.now, address=dcfg.imu.address, seed=seed + 2
        )
        app.emulators.extend([arduino_emu, lidar_emu, imu_bus])
        app.add(Part("arduino-emulator", run=arduino_emu.run, close=arduino_emu.aclose))
        app.add(Part("lidar-emulator", run=lidar_emu.run, close=lidar_emu.close))
        arduino_port = arduino_emu.port_path
        lidar_port = lidar_emu.path
        lidar_motor = lidar_emu.set_motor
        open_bus = imu_bus.reopen
        offload = False
        # The emulated chip's calibration must never be restored into the real one.
        calibration_file = "emulated-" + calibration_file

    base = ArduinoBase(dcfg.arduino, cfg.robot, app.bus, app.clock, port=arduino_port)
    lidar = RplidarDriver(dcfg.lidar, app.clock, app.bus, port=lidar_port, motor=lidar_motor)
    imu = Bno055Driver(
        dcfg.imu,
        app.clock,
        app.bus,
        calibration_path=cfg.data_path(calibration_file),
        open_bus=open_bus,
        offload=offload,
    )
    app.base, app.lidar, app.imu = base, lidar, imu
    if dcfg.mode == "emulated":
        # Hold the simulated clock while pty bytes are in flight (exact byte accounting).
        arduino_emu.pair(base)
        lidar_emu.pair(lidar)
    app.add(Part("arduino", run=base.run, close=base.close))
    app.add_halt_hook(base.halt)
    app.add(Part("lidar", run=lidar.run, close=lidar.close))
    app.add(Part("imu", run=imu.run, close=imu.close))
    notifier = SystemdNotifier(app.clock, app.bus, os.environ)
    if notifier.enabled:  # started by systemd (deploy/curio.service): READY=1 and watchdog
        app.add(Part("systemd-notify", run=notifier.run))
