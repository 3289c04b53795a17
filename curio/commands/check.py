"""``curio check``: find the rover's devices, talk to each, say how to fix what does not work.

    curio check [--config PATH] [--set KEY=VALUE]... [--arduino PATH] [--lidar PATH]
                [--i2c-bus N|emulated] [--imu-address 0x28|0x29] [--skip arduino,lidar,imu]

This module is the command: its arguments, port discovery, the table and the exit code. Each
device's own check lives in its folder (``curio/drivers/*/check.py``):

1. **Serial ports** (``serial.tools.list_ports``): the Arduino Mega 2560 (USB 2341:0042, also
   2341:0010 and 2A03:0042; clones with a CH340, 1A86:7523, are reported as possible) and the
   RPLidar's CP2102 adapter (10C4:EA60). An explicit ``--arduino`` / ``--lidar`` path wins;
   otherwise the configured port is used when it exists, else the port found by USB id.
2. **Arduino** (``curio/drivers/arduino/check.py``): opening the port resets the Mega; the check
   waits out the boot window, sends GET_INFO and HEARTBEATs and expects INFO (protocol
   version), STATE (the heartbeat echoed) and BATTERY.
3. **RPLidar** (``curio/drivers/rplidar/check.py``): STOP, GET_INFO, GET_HEALTH, then one and a
   half seconds of SCAN: revolutions per second and samples per revolution, then STOP.
4. **BNO055** (``curio/drivers/bno055/check.py``): CHIP_ID at the configured address (and the
   other one), repeated reads to spot the Raspberry Pi's clock-stretching garbage, the
   self-test result, the saved calibration.
5. **Compiled kernels** (:mod:`curio.kernels`): whether the numba cache (``numba_cache_dir``)
   holds every kernel for the installed sources (``warn`` when not: the first start compiles,
   and ``curio warmup`` fixes it).

Every row is ``ok``, ``warn`` or ``FAIL`` with what was found and, when it is not ok, what to
do. Exit code: 0 when nothing failed, 1 when something did, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from curio.core.clock import RealClock
from curio.core.config import Config, ConfigError, load_config
from curio.drivers.arduino.check import CLONE_USB_IDS, USB_IDS, check_arduino
from curio.drivers.bno055.check import check_imu
from curio.drivers.bno055.driver import open_smbus
from curio.drivers.bno055.emulator import Bno055Emulator
from curio.drivers.checks import CheckResult
from curio.drivers.rplidar.check import USB_IDS as LIDAR_USB_IDS
from curio.drivers.rplidar.check import check_lidar

__all__ = ["CheckResult", "check_arduino", "check_imu", "check_lidar", "find_ports", "main"]


# --- ports ------------------------------------------------------------------------------------
@dataclass
class PortInfo:
    """A serial port and its USB ids (0 when not USB)."""

    device: str
    vid: int
    pid: int
    description: str


def list_serial_ports() -> list[PortInfo]:
    """Every serial port the system knows."""
    from serial.tools import list_ports

    return [
        PortInfo(p.device, p.vid or 0, p.pid or 0, p.description or "")
        for p in list_ports.comports()
    ]


def find_ports(ports: list[PortInfo]) -> tuple[list[PortInfo], list[PortInfo], list[PortInfo]]:
    """Split ``ports`` into (Arduinos, CH340 clones, lidars) by USB id."""
    ids = [(p, (p.vid, p.pid)) for p in ports]
    return (
        [p for p, i in ids if i in USB_IDS],
        [p for p, i in ids if i in CLONE_USB_IDS],
        [p for p, i in ids if i in LIDAR_USB_IDS],
    )


def _choose(explicit: str | None, configured: str, found: list[PortInfo]) -> str | None:
    if explicit:
        return explicit
    if Path(configured).exists():
        return configured
    return found[0].device if found else None


def kernel_cache_row(cfg: Config) -> CheckResult:
    """The compiled kernels' cache: ``ok`` when every kernel is cached for these sources."""
    from curio import kernels

    where = kernels.describe(kernels.use_cache_dir(cfg))
    found = kernels.status()
    cold = [k.name.rsplit(".", 1)[-1] for k in found if k.cached == 0]
    if not cold:
        return CheckResult("kernels", "ok", f"all {len(found)} compiled kernels cached ({where})")
    listed = ", ".join(cold[:4]) + (" ..." if len(cold) > 4 else "")
    return CheckResult(
        "kernels", "warn", f"{len(cold)} of {len(found)} compiled kernels not cached ({where}): "
        f"{listed}; the next start compiles them first",
        "run 'curio warmup' as the user that runs Curio (on the rover: sudo -u curio "
        "/opt/curio/.venv/bin/curio warmup --config /etc/curio/config.toml)")


# --- main -------------------------------------------------------------------------------------
def format_table(results: list[CheckResult]) -> str:
    """The report as an aligned table with a fix line under each problem."""
    width = max(len(r.name) for r in results) if results else 6
    lines = [f"{'CHECK':<{width}}  {'RESULT':<6}  DETAIL"]
    for res in results:
        lines.append(f"{res.name:<{width}}  {res.status:<6}  {res.detail}")
        if res.fix:
            lines.append(f"{'':<{width}}  {'':<6}  fix: {res.fix}")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="curio check",
                                 description="Diagnose the rover's hardware and say how to fix it.")
    ap.add_argument("--config", help="config file (default: ./config.toml or the shipped one)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override one config key (repeatable), e.g. drivers.arduino.port=...")
    ap.add_argument("--arduino", help="the Arduino's serial port (default: config / USB id)")
    ap.add_argument("--lidar", help="the RPLidar's serial port (default: config / USB id)")
    ap.add_argument("--i2c-bus", help="I2C bus number, or 'emulated' for the fake BNO055 bus")
    ap.add_argument("--imu-address", help="0x28 or 0x29 (default: drivers.imu.address)")
    ap.add_argument("--skip", default="", help="checks to leave out, comma-separated: "
                    "arduino,lidar,imu,kernels")
    return ap


class _Usage(Exception):
    """Bad arguments (the message says which)."""


def _overrides(args: argparse.Namespace) -> list[str]:
    """The config overrides the arguments ask for."""
    overrides = list(args.overrides)
    if args.imu_address is not None:
        try:
            overrides.append(f"drivers.imu.address={int(args.imu_address, 0)}")
        except ValueError:
            raise _Usage("--imu-address takes 0x28 or 0x29") from None
    bus_arg = args.i2c_bus
    if bus_arg is not None and bus_arg != "emulated":
        if not bus_arg.isdigit():
            raise _Usage("--i2c-bus takes a bus number or 'emulated'")
        overrides.append(f"drivers.imu.i2c_bus={bus_arg}")
    return overrides


def _device_rows(args: argparse.Namespace, cfg: Config, skip: set[str]) -> list[CheckResult]:
    """The ports row, then each device's check (or why it could not be found)."""
    results: list[CheckResult] = []
    ports = list_serial_ports()
    arduinos, clones, lidars = find_ports(ports)
    listing = ", ".join(f"{p.device} ({p.vid:04X}:{p.pid:04X})" for p in ports if p.vid) or \
        "no USB serial devices"
    results.append(CheckResult("ports", "ok", listing))
    if "arduino" not in skip:
        path = _choose(args.arduino, cfg.drivers.arduino.port, arduinos + clones)
        if path is None:
            results.append(CheckResult(
                "arduino", "FAIL", "no Arduino Mega found (USB 2341:0042)",
                "plug the Mega's USB cable into the Pi; a clone may use another id: pass "
                "--arduino /dev/ttyUSBn"))
        else:
            results.append(check_arduino(path, cfg))
    if "lidar" not in skip:
        path = _choose(args.lidar, cfg.drivers.lidar.port, lidars)
        if path is None:
            results.append(CheckResult(
                "lidar", "FAIL", "no RPLidar found (CP2102 USB 10C4:EA60)",
                "plug the lidar's USB adapter in (the laser's own cable into the adapter too)"))
        else:
            results.append(check_lidar(path, cfg))
    if "imu" not in skip:
        if args.i2c_bus == "emulated":
            fake = Bno055Emulator(None, RealClock().now, power_on_s=0.0)
            results.append(check_imu(fake.reopen, cfg, "the emulated I2C bus"))
        else:
            n = cfg.drivers.imu.i2c_bus
            results.append(check_imu(lambda: open_smbus(n), cfg, f"/dev/i2c-{n}"))
    return results


def main(argv: list[str]) -> int:
    """Run ``curio check``; return the exit code (0 all good, 1 a check failed, 2 bad usage)."""
    args = _parser().parse_args(argv)
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    unknown = skip - {"arduino", "lidar", "imu", "kernels"}
    if unknown:
        print(f"curio check: --skip takes arduino, lidar, imu, kernels; got {sorted(unknown)}",
              file=sys.stderr)
        return 2
    try:
        cfg = load_config(args.config, _overrides(args))
    except (_Usage, ConfigError) as exc:
        print(f"curio check: {exc}", file=sys.stderr)
        return 2
    if cfg.drivers.mode != "real":
        print(f"note: the config runs drivers.mode = {cfg.drivers.mode!r} (no hardware: "
              "'curio run' would not use these devices); this checks the hardware anyway. On "
              "the rover set drivers.mode = \"real\".\n")
    results = _device_rows(args, cfg, skip)
    if "kernels" not in skip:
        results.append(kernel_cache_row(cfg))
    print(format_table(results))
    failed = [r.name for r in results if r.status == "FAIL"]
    if failed:
        print(f"\nFAILED: {', '.join(failed)}")
    elif skip >= {"arduino", "lidar", "imu"}:
        print("\nno device checked: arduino, lidar and imu were all skipped (--skip)")
    else:
        checked = sorted({"arduino", "lidar", "imu"} - skip)
        print(f"\nall checks passed ({', '.join(checked)})")
    return 1 if failed else 0
