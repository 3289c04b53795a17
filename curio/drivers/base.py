"""The base-driver interface: what the application needs from the rover's base.

Two implementations: :class:`~curio.drivers.arduino.driver.ArduinoBase` (the Arduino Mega and its
LX-16A servos, in ``real`` and ``emulated`` mode) and :class:`~curio.sim.base.SimBase` (the
simulated rover, in ``sim`` mode). Either executes ``/cmd_vel`` while :meth:`BaseDriver.run`
runs, stops the wheels at once on :meth:`BaseDriver.halt` (the application's first shutdown step
and its halt hook) and releases what it holds on :meth:`BaseDriver.close`. Which one runs is
decided by the ``drivers.mode`` table (:mod:`curio.drivers.modes`).
"""

from __future__ import annotations

from typing import Protocol

__all__ = ["BaseDriver"]


class BaseDriver(Protocol):
    """The rover's base: ``/cmd_vel`` in, wheels turning."""

    async def run(self) -> None:
        """Execute ``/cmd_vel`` until cancelled."""
        ...

    async def halt(self) -> None:
        """Zero every wheel duty now (and keep them stopped)."""
        ...

    async def close(self) -> None:
        """Release the link (the application's last shutdown step)."""
        ...
