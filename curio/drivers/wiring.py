"""Driver wiring: odometry in every mode; device drivers and emulators when not in sim mode.

* every mode: :class:`~curio.drivers.odometry.WheelOdometry` (``/wheels`` → ``/wheel_odom``);
* ``sim`` mode: nothing else (the simulator publishes the sensors and its ``SimBase`` is the
  base, see ``curio/sim/wiring.py``);
* ``emulated`` and ``real``: ``curio.drivers.hw_wiring.build_device_drivers(app)`` builds the
  Arduino, RPLidar and BNO055 drivers (and, when emulated, the device emulators).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from curio.drivers.odometry import WheelOdometry

if TYPE_CHECKING:
    from curio.app import App


def build_drivers(app: App) -> None:
    """Construct the drivers from ``app.cfg`` and register them on ``app``."""
    from curio.app import Part

    odometry = WheelOdometry(app.cfg, app.bus, app.clock)
    app.add(Part("odometry", run=odometry.run, close=odometry.close))
    if app.cfg.drivers.mode != "sim":
        # Imported lazily by name: the device drivers are another subsystem's module.
        hw = importlib.import_module("curio.drivers.hw_wiring")
        hw.build_device_drivers(app)
