"""What every device's part of ``curio check`` shares: the result row and the serial helpers.

Each device folder has a ``check.py`` (``curio/drivers/arduino/check.py``,
``curio/drivers/rplidar/check.py``, ``curio/drivers/bno055/check.py``) that talks to the device
once, blocking, and returns a :class:`CheckResult`; ``curio/commands/check.py`` is the command
(arguments, port discovery, the table, the exit code). Timing here is wall time on purpose: the
check runs before (and without) the application and its clock.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.clock import RealClock

__all__ = ["CheckResult", "open_error", "open_serial", "read_for"]


@dataclass
class CheckResult:
    """One row of the report: ``status`` is ``ok``, ``warn`` or ``FAIL``."""

    name: str
    status: str
    detail: str
    fix: str = ""


def open_serial(path: str, baud: int) -> Any:
    """Open the serial port ``path`` at ``baud`` (reads time out after 0.05 s); the caller
    closes it."""
    import serial

    return serial.Serial(path, baud, timeout=0.05)


def read_for(ser: Any, seconds: float, until: Callable[[bytes], bool] | None = None) -> bytes:
    """Read for up to ``seconds`` (wall time), or until ``until(data)`` holds."""
    clock = RealClock()
    deadline = clock.now() + seconds
    data = bytearray()
    while clock.now() < deadline:
        chunk = ser.read(4096)
        if chunk:
            data += chunk
            if until is not None and until(bytes(data)):
                break
    return bytes(data)


def open_error(what: str, path: str, exc: Exception) -> CheckResult:
    """The row for a port that would not open, with the likely fix."""
    text = str(exc)
    if "ermission" in text:
        fix = ("add the user to the 'dialout' group (sudo usermod -aG dialout $USER) and log in "
               "again")
    elif "No such file" in text or "could not open" in text:
        fix = (f"is the {what} plugged in? `ls -l /dev/serial/by-id/`; the udev rules in "
               "deploy/99-curio.rules create /dev/curio-arduino and /dev/curio-lidar")
    else:
        fix = "is another program (a running curio?) holding the port? `fuser " + path + "`"
    return CheckResult(what, "FAIL", f"cannot open {path}: {exc}", fix)
