"""The BNO055's part of ``curio check``: CHIP_ID at the configured address (and the other one),
repeated reads to spot the Raspberry Pi's clock-stretching garbage, the self-test result and the
saved calibration. Blocking, wall time.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable

from curio.core.clock import RealClock, wall_sleep
from curio.core.config import Config
from curio.drivers.bno055 import protocol as r
from curio.drivers.bno055.driver import BAUD_FIX, SMBusLike
from curio.drivers.checks import CheckResult

__all__ = ["check_imu"]


def _read_ids(dev: SMBusLike, addr: int) -> tuple[list[int], int]:
    """Up to 20 CHIP_ID reads at ``addr`` within about 1.5 s: the ids read and the I/O errors
    (gives up after 1 s when nothing answers)."""
    ids: list[int] = []
    errors = 0
    clock = RealClock()
    deadline = clock.now() + 1.0
    while len(ids) < 20 and clock.now() < deadline + 0.5:
        try:
            ids.append(dev.read_byte_data(addr, r.Reg.CHIP_ID))
        except OSError:
            errors += 1
            if not ids and clock.now() > deadline:
                break
            wall_sleep(0.02)
    return ids, errors


def _nobody(dev: SMBusLike, addr: int, where: str, i2c_bus: int) -> CheckResult:
    """The row when nothing answers at ``addr``: is the chip at the other address?"""
    other = 0x29 if addr == 0x28 else 0x28
    with contextlib.suppress(OSError):
        if dev.read_byte_data(other, r.Reg.CHIP_ID) == r.CHIP_ID_VALUE:
            return CheckResult(
                "imu", "FAIL", f"no chip at 0x{addr:02X} on {where}, but a BNO055 at "
                f"0x{other:02X}",
                f"set drivers.imu.address = 0x{other:02X} in config.toml (the ADR pin "
                "selects the address)",
            )
    return CheckResult(
        "imu", "FAIL", f"nothing answers at 0x28 or 0x29 on {where}",
        "check the wiring (SDA to GPIO2, SCL to GPIO3, VIN 3.3 V, GND) and run "
        f"`i2cdetect -y {i2c_bus}`",
    )


def _describe(dev: SMBusLike, addr: int, where: str) -> tuple[str, CheckResult | None]:
    """The chip's software version and self-test result; a failed self-test is a FAIL row."""
    detail = f"BNO055 at 0x{addr:02X} on {where}"
    with contextlib.suppress(OSError):
        sw = dev.read_byte_data(addr, r.Reg.SW_REV_LSB) | (
            dev.read_byte_data(addr, r.Reg.SW_REV_MSB) << 8)
        detail += f", software 0x{sw:04X}"
    with contextlib.suppress(OSError):
        st = dev.read_byte_data(addr, r.Reg.ST_RESULT)
        detail += f", self-test 0x{st:X}"
        if st & 0x0F != 0x0F:
            return detail, CheckResult("imu", "FAIL", detail,
                                       "the power-on self-test failed (bits: ACC MAG GYR MCU): "
                                       "power-cycle; replace the board if it persists")
    return detail, None


def _calibration_note(cfg: Config) -> str:
    """What the saved calibration profile says (or that there is none yet)."""
    cal = cfg.data_path(cfg.drivers.imu.calibration_file)
    if not cal.is_file():
        return "; no saved calibration yet (saved automatically once calibrated)"
    try:
        levels = json.loads(cal.read_text("utf-8")).get("levels")
        return f"; saved calibration {cal} (levels {levels})"
    except (ValueError, OSError):
        return f"; calibration file {cal} is unreadable (it will be rewritten)"


def _identify(dev: SMBusLike, cfg: Config, where: str) -> CheckResult:
    """Identify the chip on the open bus ``dev``."""
    addr = cfg.drivers.imu.address
    ids, errors = _read_ids(dev, addr)
    if not ids:
        return _nobody(dev, addr, where, cfg.drivers.imu.i2c_bus)
    good = sum(1 for i in ids if i == r.CHIP_ID_VALUE)
    if good == 0:
        return CheckResult(
            "imu", "FAIL", f"the chip at 0x{addr:02X} reports id 0x{ids[0]:02X}, not 0xA0",
            "another device sits at this address, or the bus corrupts data: " + BAUD_FIX,
        )
    detail, failed = _describe(dev, addr, where)
    if failed is not None:
        return failed
    detail += _calibration_note(cfg)
    bad = len(ids) - good + errors
    if bad:
        return CheckResult(
            "imu", "warn", detail + f"; {bad} of {len(ids) + errors} reads failed or were "
            "garbled", BAUD_FIX,
        )
    return CheckResult("imu", "ok", detail)


def check_imu(open_bus: Callable[[], SMBusLike], cfg: Config, where: str) -> CheckResult:
    """Identify the BNO055 on the bus ``open_bus()`` returns (``where`` names it)."""
    try:
        dev = open_bus()
    except FileNotFoundError:
        return CheckResult(
            "imu", "FAIL", f"{where} does not exist",
            "enable I2C: sudo raspi-config nonint do_i2c 0 (or dtparam=i2c_arm=on in "
            "/boot/firmware/config.txt) and reboot",
        )
    except PermissionError:
        return CheckResult("imu", "FAIL", f"no permission for {where}",
                           "sudo usermod -aG i2c $USER, then log in again")
    try:
        return _identify(dev, cfg, where)
    finally:
        with contextlib.suppress(Exception):
            dev.close()
