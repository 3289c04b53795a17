"""The RPLidar's part of ``curio check``: STOP, GET_INFO, GET_HEALTH, then one and a half
seconds of SCAN (revolutions per second, samples per revolution), then STOP. Blocking, wall time.
"""

from __future__ import annotations

import contextlib
from typing import Any

from curio.core.clock import wall_sleep
from curio.core.config import Config
from curio.drivers.checks import CheckResult, open_error, open_serial, read_for
from curio.drivers.rplidar import protocol as rp

__all__ = ["USB_IDS", "check_lidar"]

USB_IDS = {(0x10C4, 0xEA60)}  # the A1's CP2102 USB adapter (VID, PID)


def _identify(ser: Any, path: str) -> tuple[rp.DeviceInfo, rp.HealthStatus] | CheckResult:
    """STOP, GET_INFO and GET_HEALTH: the device and its health, or the row saying why not."""
    ser.write(rp.encode_request(rp.Cmd.STOP))
    wall_sleep(0.02)
    ser.reset_input_buffer()
    ser.write(rp.encode_request(rp.Cmd.GET_INFO))
    data = read_for(ser, 1.0, lambda d: len(d) >= 27)
    if len(data) < 27 or data[:7] != rp.INFO_DESCRIPTOR:
        what = f"{len(data)} bytes" if data else "nothing"
        return CheckResult(
            "lidar", "FAIL", f"{path} answered GET_INFO with {what}",
            "is this really the RPLidar (the CP2102 adapter, USB 10C4:EA60) and not the "
            "Arduino? Check the lidar's cable to its adapter board and its 5 V supply",
        )
    info = rp.DeviceInfo.decode(data[7:27])
    ser.write(rp.encode_request(rp.Cmd.GET_HEALTH))
    data = read_for(ser, 1.0, lambda d: len(d) >= 10)
    if len(data) < 10 or data[:7] != rp.HEALTH_DESCRIPTOR:
        return CheckResult("lidar", "FAIL", f"{info.describe()}; no GET_HEALTH answer",
                           "power-cycle the lidar")
    health = rp.HealthStatus.decode(data[7:10])
    if health.status == rp.HealthLevel.ERROR:
        return CheckResult(
            "lidar", "FAIL",
            f"{info.describe()}; health ERROR (protection stop, code "
            f"0x{health.error_code:04X})",
            "curio sends RESET by itself at start; if it persists, power-cycle the lidar; "
            "repeated protection stops mean the laser or motor is damaged",
        )
    return info, health


def _scan(ser: Any, scan_s: float) -> bytes:
    """Motor on, SCAN for ``scan_s`` seconds, STOP, motor off; the bytes received."""
    with contextlib.suppress(OSError, ValueError):
        ser.dtr = False  # A1: motor on (a pty has no DTR)
    ser.write(rp.encode_request(rp.Cmd.SCAN))
    data = read_for(ser, scan_s)
    ser.write(rp.encode_request(rp.Cmd.STOP))
    with contextlib.suppress(OSError, ValueError):
        ser.dtr = True
    return data


def _verdict(info: rp.DeviceInfo, health: rp.HealthStatus, data: bytes,
             scan_s: float) -> CheckResult:
    """The row for a lidar that answered: its scan rate, samples and returns."""
    detail = f"{info.describe()}; health {health.name}"
    if data[:7] != rp.SCAN_DESCRIPTOR:
        return CheckResult("lidar", "FAIL", detail + "; no SCAN descriptor",
                           "power-cycle the lidar")
    dec = rp.NodeStreamDecoder()
    asm = rp.ScanAssembler()
    revs = asm.feed(dec.feed(data[7:]))
    if not revs:
        return CheckResult(
            "lidar", "FAIL", detail + f"; no full revolution in {scan_s:.1f} s "
            f"({len(data) - 7} bytes)",
            "the motor does not spin: the A1's motor follows DTR and needs 5 V at ~0.5 A; use a "
            "powered USB port or hub",
        )
    samples = sum(len(r) for r in revs) / len(revs)
    valid = sum(int((r.distance_mm > 0).sum()) for r in revs) / len(revs)
    detail += (f"; {len(revs) / scan_s:.1f} rev/s, {samples:.0f} samples/rev "
               f"({valid:.0f} with a return)")
    if health.status == rp.HealthLevel.WARNING:
        return CheckResult("lidar", "warn", detail, "health WARNING: keep an eye on it")
    if valid < 0.1 * samples:
        return CheckResult("lidar", "warn", detail,
                           "almost no returns: is the lidar covered, or the lens dirty?")
    return CheckResult("lidar", "ok", detail)


def check_lidar(path: str, cfg: Config, scan_s: float = 1.5) -> CheckResult:
    """GET_INFO, GET_HEALTH and a short scan from the RPLidar on ``path``."""
    try:
        ser = open_serial(path, cfg.drivers.lidar.baud)
    except Exception as exc:
        return open_error("lidar", path, exc)
    try:
        found = _identify(ser, path)
        if isinstance(found, CheckResult):
            return found
        info, health = found
        data = _scan(ser, scan_s)
    finally:
        ser.close()
    return _verdict(info, health, data, scan_s)
