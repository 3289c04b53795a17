"""``curio check``: find the rover's devices, talk to each, say how to fix what does not work.

    curio check [--config PATH] [--set KEY=VALUE]... [--arduino PATH] [--lidar PATH]
                [--i2c-bus N|emulated] [--imu-address 0x28|0x29] [--skip arduino,lidar,imu]

1. **Serial ports** (``serial.tools.list_ports``): the Arduino Mega 2560 (USB 2341:0042, also
   2341:0010 and 2A03:0042; clones with a CH340, 1A86:7523, are reported as possible) and the
   RPLidar's CP2102 adapter (10C4:EA60). An explicit ``--arduino`` / ``--lidar`` path wins;
   otherwise the configured port is used when it exists, else the port found by USB id.
2. **Arduino**: opening the port resets the Mega; the check waits out the boot window, sends
   GET_INFO and HEARTBEATs (H5's protocol, ``curio/drivers/arduino/protocol.py``) and expects
   INFO (protocol version), STATE (the heartbeat echoed) and BATTERY.
3. **RPLidar**: STOP, GET_INFO, GET_HEALTH, then one and a half seconds of SCAN: revolutions per
   second and samples per revolution, then STOP.
4. **BNO055**: CHIP_ID at the configured address (and the other one), repeated reads to spot
   the Raspberry Pi's clock-stretching garbage, the self-test result, the saved calibration.

Every row is ``ok``, ``warn`` or ``FAIL`` with what was found and, when it is not ok, what to
do. Exit code: 0 when nothing failed, 1 when something did, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from curio.core.clock import RealClock, wall_sleep
from curio.core.config import Config, ConfigError, load_config

__all__ = ["CheckResult", "check_arduino", "check_imu", "check_lidar", "find_ports", "main"]

ARDUINO_IDS = {(0x2341, 0x0042), (0x2341, 0x0010), (0x2A03, 0x0042)}
CLONE_IDS = {(0x1A86, 0x7523)}
LIDAR_IDS = {(0x10C4, 0xEA60)}


@dataclass
class CheckResult:
    """One row of the report: ``status`` is ``ok``, ``warn`` or ``FAIL``."""

    name: str
    status: str
    detail: str
    fix: str = ""


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
        [p for p, i in ids if i in ARDUINO_IDS],
        [p for p, i in ids if i in CLONE_IDS],
        [p for p, i in ids if i in LIDAR_IDS],
    )


def _choose(explicit: str | None, configured: str, found: list[PortInfo]) -> str | None:
    if explicit:
        return explicit
    if Path(configured).exists():
        return configured
    return found[0].device if found else None


# --- serial helpers ---------------------------------------------------------------------------
@contextlib.contextmanager
def _open_serial(path: str, baud: int) -> Iterator[Any]:
    import serial

    ser = serial.Serial(path, baud, timeout=0.05)
    try:
        yield ser
    finally:
        ser.close()


def _read_for(ser: Any, seconds: float, until: Callable[[bytes], bool] | None = None) -> bytes:
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


def _open_error(what: str, path: str, exc: Exception) -> CheckResult:
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


# --- Arduino ----------------------------------------------------------------------------------
def check_arduino(path: str, cfg: Config) -> CheckResult:
    """Handshake with the base controller firmware on ``path``."""
    from curio.drivers.arduino import protocol as p

    acfg = cfg.drivers.arduino
    try:
        cm = _open_serial(path, acfg.baud)
        ser = cm.__enter__()
    except Exception as exc:
        return _open_error("arduino", path, exc)
    try:
        dec = p.FrameDecoder()
        frames: list[Any] = []
        raw = bytearray()
        clock = RealClock()
        start = clock.now()
        # The Mega resets when the port opens: wait for it to announce itself (or time out).
        deadline = start + acfg.boot_wait_s + 1.5
        seq = 0
        info = state = battery = None
        echoed = False
        next_ask = start + acfg.boot_wait_s
        while clock.now() < deadline:
            chunk = ser.read(4096)
            raw += chunk
            for frame in dec.feed(chunk):
                try:
                    msg = p.decode_message(frame)
                except p.ProtocolError:
                    continue
                frames.append(msg)
                if isinstance(msg, p.Info):
                    info = msg
                elif isinstance(msg, p.State):
                    state = msg
                    if msg.last_host_ms == 4242:
                        echoed = True
                elif isinstance(msg, p.Battery):
                    battery = msg
            if frames and clock.now() >= next_ask:
                next_ask = clock.now() + 0.3
                for msg in (p.GetInfo(), p.Heartbeat(4242)):
                    ser.write(p.encode(msg, seq))
                    seq = (seq + 1) & 0xFF
            if info is not None and echoed:
                break
            if not frames and not raw and next_ask <= clock.now():
                # Nothing at all after the boot window: ask anyway (boards without auto-reset).
                ser.write(p.encode(p.GetInfo(), seq))
                seq = (seq + 1) & 0xFF
                next_ask = clock.now() + 0.5
    finally:
        cm.__exit__(None, None, None)
    if not frames:
        if raw:
            return CheckResult(
                "arduino", "FAIL",
                f"{len(raw)} bytes from {path} but no valid Curio frame "
                f"({dec.stats.crc_errors} CRC errors)",
                "wrong device (the lidar?), wrong baud rate, or old rosserial firmware: flash "
                "the Curio firmware (firmware/README.md)",
            )
        return CheckResult(
            "arduino", "FAIL", f"no answer from {path}",
            "flash the Curio firmware (firmware/README.md: arduino-cli upload); check the USB "
            "cable and that the Mega's power LED is on",
        )
    parts = []
    status, fix = "ok", ""
    if info is not None:
        parts.append(f"firmware {info.fw_major}.{info.fw_minor} protocol {info.proto_ver}")
        if info.proto_ver != p.PROTO_VERSION:
            status = "FAIL"
            fix = (f"the firmware speaks protocol {info.proto_ver}, this curio "
                   f"{p.PROTO_VERSION}: flash the matching firmware (firmware/README.md)")
    else:
        status, fix = "warn", "no INFO answer to GET_INFO: reflash the firmware"
    if state is not None:
        parts.append(f"state {p.McuState(state.state).name}")
    if battery is not None:
        volts = battery.servo_vin_mv / 1000.0
        parts.append(f"servo supply {volts:.2f} V")
        if volts < cfg.bt.low_battery_v and status == "ok":
            status, fix = "warn", "the servo battery is low: charge it"
    parts.append("heartbeat echoed" if echoed else "heartbeat NOT echoed")
    if not echoed and status == "ok":
        status, fix = "warn", "the firmware does not echo HEARTBEAT: check the TX line / reflash"
    return CheckResult("arduino", status, f"{path}: " + ", ".join(parts), fix)


# --- RPLidar ----------------------------------------------------------------------------------
def check_lidar(path: str, cfg: Config, scan_s: float = 1.5) -> CheckResult:
    """GET_INFO, GET_HEALTH and a short scan from the RPLidar on ``path``."""
    from curio.drivers.rplidar import protocol as rp

    try:
        cm = _open_serial(path, cfg.drivers.lidar.baud)
        ser = cm.__enter__()
    except Exception as exc:
        return _open_error("lidar", path, exc)
    try:
        ser.write(rp.encode_request(rp.Cmd.STOP))
        wall_sleep(0.02)
        ser.reset_input_buffer()
        ser.write(rp.encode_request(rp.Cmd.GET_INFO))
        data = _read_for(ser, 1.0, lambda d: len(d) >= 27)
        if len(data) < 27 or data[:7] != rp.INFO_DESCRIPTOR:
            what = f"{len(data)} bytes" if data else "nothing"
            return CheckResult(
                "lidar", "FAIL", f"{path} answered GET_INFO with {what}",
                "is this really the RPLidar (the CP2102 adapter, USB 10C4:EA60) and not the "
                "Arduino? Check the lidar's cable to its adapter board and its 5 V supply",
            )
        info = rp.DeviceInfo.decode(data[7:27])
        ser.write(rp.encode_request(rp.Cmd.GET_HEALTH))
        data = _read_for(ser, 1.0, lambda d: len(d) >= 10)
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
        with contextlib.suppress(OSError, ValueError):
            ser.dtr = False  # A1: motor on (a pty has no DTR)
        ser.write(rp.encode_request(rp.Cmd.SCAN))
        data = _read_for(ser, scan_s)
        ser.write(rp.encode_request(rp.Cmd.STOP))
        with contextlib.suppress(OSError, ValueError):
            ser.dtr = True
    finally:
        cm.__exit__(None, None, None)
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


# --- BNO055 -----------------------------------------------------------------------------------
def check_imu(open_bus: Callable[[], Any], cfg: Config, where: str) -> CheckResult:
    """Identify the BNO055 on the bus ``open_bus()`` returns."""
    from curio.drivers.bno055 import protocol as r
    from curio.drivers.bno055.driver import BAUD_FIX

    icfg = cfg.drivers.imu
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
        addr = icfg.address
        other = 0x29 if addr == 0x28 else 0x28
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
        if not ids:
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
                f"`i2cdetect -y {icfg.i2c_bus}`",
            )
        good = sum(1 for i in ids if i == r.CHIP_ID_VALUE)
        if good == 0:
            return CheckResult(
                "imu", "FAIL", f"the chip at 0x{addr:02X} reports id 0x{ids[0]:02X}, not 0xA0",
                "another device sits at this address, or the bus corrupts data: " + BAUD_FIX,
            )
        detail = f"BNO055 at 0x{addr:02X} on {where}"
        with contextlib.suppress(OSError):
            sw = dev.read_byte_data(addr, r.Reg.SW_REV_LSB) | (
                dev.read_byte_data(addr, r.Reg.SW_REV_MSB) << 8)
            detail += f", software 0x{sw:04X}"
        with contextlib.suppress(OSError):
            st = dev.read_byte_data(addr, r.Reg.ST_RESULT)
            detail += f", self-test 0x{st:X}"
            if st & 0x0F != 0x0F:
                return CheckResult("imu", "FAIL", detail,
                                   "the power-on self-test failed (bits: ACC MAG GYR MCU): "
                                   "power-cycle; replace the board if it persists")
        cal = cfg.data_path(icfg.calibration_file)
        if cal.is_file():
            try:
                levels = json.loads(cal.read_text("utf-8")).get("levels")
                detail += f"; saved calibration {cal} (levels {levels})"
            except (ValueError, OSError):
                detail += f"; calibration file {cal} is unreadable (it will be rewritten)"
        else:
            detail += "; no saved calibration yet (saved automatically once calibrated)"
        bad = len(ids) - good + errors
        if bad:
            return CheckResult(
                "imu", "warn", detail + f"; {bad} of {len(ids) + errors} reads failed or were "
                "garbled", BAUD_FIX,
            )
        return CheckResult("imu", "ok", detail)
    finally:
        with contextlib.suppress(Exception):
            dev.close()


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
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--arduino", help="the Arduino's serial port (default: config / USB id)")
    ap.add_argument("--lidar", help="the RPLidar's serial port (default: config / USB id)")
    ap.add_argument("--i2c-bus", help="I2C bus number, or 'emulated' for the fake BNO055 bus")
    ap.add_argument("--imu-address", help="0x28 or 0x29 (default: drivers.imu.address)")
    ap.add_argument("--skip", default="", help="comma-separated: arduino,lidar,imu")
    return ap


def main(argv: list[str]) -> int:
    """Run ``curio check``; return the exit code (0 all good, 1 a check failed, 2 bad usage)."""
    args = _parser().parse_args(argv)
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    unknown = skip - {"arduino", "lidar", "imu"}
    if unknown:
        print(f"curio check: --skip takes arduino, lidar, imu; got {sorted(unknown)}",
              file=sys.stderr)
        return 2
    overrides = list(args.overrides)
    if args.imu_address is not None:
        try:
            overrides.append(f"drivers.imu.address={int(args.imu_address, 0)}")
        except ValueError:
            print("curio check: --imu-address takes 0x28 or 0x29", file=sys.stderr)
            return 2
    bus_arg = args.i2c_bus
    if bus_arg is not None and bus_arg != "emulated":
        if not bus_arg.isdigit():
            print("curio check: --i2c-bus takes a bus number or 'emulated'", file=sys.stderr)
            return 2
        overrides.append(f"drivers.imu.i2c_bus={bus_arg}")
    try:
        cfg = load_config(args.config, overrides)
    except ConfigError as exc:
        print(f"curio check: {exc}", file=sys.stderr)
        return 2
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
        if bus_arg == "emulated":
            from curio.drivers.bno055.emulator import Bno055Emulator

            fake = Bno055Emulator(None, RealClock().now, power_on_s=0.0)
            results.append(check_imu(fake.reopen, cfg, "the emulated I2C bus"))
        else:
            from curio.drivers.bno055.driver import open_smbus

            n = cfg.drivers.imu.i2c_bus
            results.append(check_imu(lambda: open_smbus(n), cfg, f"/dev/i2c-{n}"))
    print(format_table(results))
    failed = [r.name for r in results if r.status == "FAIL"]
    print(f"\n{'FAILED: ' + ', '.join(failed) if failed else 'all checks passed'}")
    return 1 if failed else 0
