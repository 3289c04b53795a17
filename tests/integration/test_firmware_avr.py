"""The firmware sketch compiles for the real target (ATmega2560) with Debian's AVR toolchain
(avr-gcc, avr-libc and the Arduino AVR core; firmware/avr.mk, no Arduino IDE).

The host build (test_firmware_host.py) proves the behaviour; this proves the same sources
build for the Mega and fit its 256 KiB of flash and 8 KiB of SRAM with room to spare.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from curio.core.config import REPO_ROOT

ARDUINO_CORE = Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h")

pytestmark = pytest.mark.skipif(
    not os.environ.get("CI") and (shutil.which("avr-gcc") is None or not ARDUINO_CORE.is_file()),
    reason="gcc-avr/arduino-core-avr not installed (scripts/test installs them)")


def test_sketch_builds_for_the_mega(tmp_path: Path) -> None:
    result = subprocess.run(
        ["make", "-f", "avr.mk", f"OBJDIR={tmp_path / 'obj'}"],
        cwd=REPO_ROOT / "firmware", capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert (tmp_path / "obj" / "curio_base.hex").stat().st_size > 1000
    size = subprocess.run(["avr-size", "--mcu=atmega2560", "-C",
                           str(tmp_path / "obj" / "curio_base.elf")],
                          capture_output=True, text=True, check=True).stdout
    program = int(re.search(r"Program:\s+(\d+) bytes", size).group(1))  # type: ignore[union-attr]
    data = int(re.search(r"Data:\s+(\d+) bytes", size).group(1))  # type: ignore[union-attr]
    assert program < 256 * 1024 // 2  # flash, with room for growth
    assert data < 8 * 1024 // 2  # SRAM: stack and serial buffers need the rest
    # Our own sources compile without warnings (the Arduino core's are not ours).
    ours = [line for line in result.stderr.splitlines()
            if "warning" in line and "curio_base/" in line]
    assert not ours, "\n".join(ours)
