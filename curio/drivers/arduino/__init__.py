"""The Arduino Mega base link: protocol, LX-16A packets, driver, byte-exact emulator and check.

* :mod:`~curio.drivers.arduino.protocol` — the framed Pi ↔ Mega protocol (pure).
* :mod:`~curio.drivers.arduino.lx16a` — LX-16A bus-servo packets (pure).
* :mod:`~curio.drivers.arduino.driver` — :class:`ArduinoBase`, the asyncio driver.
* :mod:`~curio.drivers.arduino.emulator` — :class:`ArduinoEmulator` on a pseudo-terminal.
* :mod:`~curio.drivers.arduino.check` — its part of ``curio check``.

The firmware in ``firmware/`` implements the same protocol in portable C++.
"""

from __future__ import annotations

from curio.drivers.arduino.driver import ArduinoBase
from curio.drivers.arduino.emulator import ArduinoEmulator

__all__ = ["ArduinoBase", "ArduinoEmulator"]
