"""The Arduino's part of ``curio check``: a handshake with the base controller firmware.

Opening the port resets the Mega: the check waits out the boot window, sends GET_INFO and
HEARTBEATs (:mod:`curio.drivers.arduino.protocol`) and expects INFO (the protocol version),
STATE (the heartbeat echoed) and BATTERY. Blocking, wall time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from curio.core.clock import RealClock
from curio.core.config import ArduinoConfig, Config
from curio.drivers.arduino import protocol as p
from curio.drivers.checks import CheckResult, open_error, open_serial

__all__ = ["CLONE_USB_IDS", "USB_IDS", "check_arduino"]

USB_IDS = {(0x2341, 0x0042), (0x2341, 0x0010), (0x2A03, 0x0042)}  # Mega 2560 (VID, PID)
CLONE_USB_IDS = {(0x1A86, 0x7523)}  # CH340 clones: possibly a Mega
ECHO_MS = 4242  # the heartbeat stamp the firmware must echo in STATE


@dataclass
class _Heard:
    """What the board said during the handshake."""

    frames: list[Any] = field(default_factory=list)
    raw: bytearray = field(default_factory=bytearray)
    crc_errors: int = 0
    info: p.Info | None = None
    state: p.State | None = None
    battery: p.Battery | None = None
    echoed: bool = False

    def take(self, msg: Any) -> None:
        """Note one decoded message."""
        self.frames.append(msg)
        if isinstance(msg, p.Info):
            self.info = msg
        elif isinstance(msg, p.State):
            self.state = msg
            if msg.last_host_ms == ECHO_MS:
                self.echoed = True
        elif isinstance(msg, p.Battery):
            self.battery = msg


def _handshake(ser: Any, acfg: ArduinoConfig) -> _Heard:
    """Listen through the boot window, then ask for INFO and a heartbeat echo (wall time)."""
    heard = _Heard()
    dec = p.FrameDecoder()
    clock = RealClock()
    start = clock.now()
    # The Mega resets when the port opens: wait for it to announce itself (or time out).
    deadline = start + acfg.boot_wait_s + 1.5
    seq = 0
    next_ask = start + acfg.boot_wait_s
    while clock.now() < deadline:
        chunk = ser.read(4096)
        heard.raw += chunk
        for frame in dec.feed(chunk):
            try:
                heard.take(p.decode_message(frame))
            except p.ProtocolError:
                continue
        if heard.frames and clock.now() >= next_ask:
            next_ask = clock.now() + 0.3
            for msg in (p.GetInfo(), p.Heartbeat(ECHO_MS)):
                ser.write(p.encode(msg, seq))
                seq = (seq + 1) & 0xFF
        if heard.info is not None and heard.echoed:
            break
        if not heard.frames and not heard.raw and next_ask <= clock.now():
            # Nothing at all after the boot window: ask anyway (boards without auto-reset).
            ser.write(p.encode(p.GetInfo(), seq))
            seq = (seq + 1) & 0xFF
            next_ask = clock.now() + 0.5
    heard.crc_errors = dec.stats.crc_errors
    return heard


def _silent(path: str, heard: _Heard) -> CheckResult:
    """The row when no valid frame came back."""
    if heard.raw:
        return CheckResult(
            "arduino", "FAIL",
            f"{len(heard.raw)} bytes from {path} but no valid Curio frame "
            f"({heard.crc_errors} CRC errors)",
            "wrong device (the lidar?), wrong baud rate, or old rosserial firmware: flash "
            "the Curio firmware (firmware/README.md)",
        )
    return CheckResult(
        "arduino", "FAIL", f"no answer from {path}",
        "flash the Curio firmware (firmware/README.md: arduino-cli upload); check the USB "
        "cable and that the Mega's power LED is on",
    )


def _verdict(path: str, heard: _Heard, cfg: Config) -> CheckResult:
    """The row for a board that answered: firmware, state, supply, heartbeat echo."""
    parts = []
    status, fix = "ok", ""
    info = heard.info
    if info is not None:
        parts.append(f"firmware {info.fw_major}.{info.fw_minor} protocol {info.proto_ver}")
        if info.proto_ver != p.PROTO_VERSION:
            status = "FAIL"
            fix = (f"the firmware speaks protocol {info.proto_ver}, this curio "
                   f"{p.PROTO_VERSION}: flash the matching firmware (firmware/README.md)")
    else:
        status, fix = "warn", "no INFO answer to GET_INFO: reflash the firmware"
    if heard.state is not None:
        parts.append(f"state {p.McuState(heard.state.state).name}")
    if heard.battery is not None:
        volts = heard.battery.servo_vin_mv / 1000.0
        parts.append(f"servo supply {volts:.2f} V")
        if volts < cfg.bt.low_battery_v and status == "ok":
            status, fix = "warn", "the servo battery is low: charge it"
    parts.append("heartbeat echoed" if heard.echoed else "heartbeat NOT echoed")
    if not heard.echoed and status == "ok":
        status, fix = "warn", "the firmware does not echo HEARTBEAT: check the TX line / reflash"
    return CheckResult("arduino", status, f"{path}: " + ", ".join(parts), fix)


def check_arduino(path: str, cfg: Config) -> CheckResult:
    """Handshake with the base controller firmware on ``path``."""
    try:
        ser = open_serial(path, cfg.drivers.arduino.baud)
    except Exception as exc:
        return open_error("arduino", path, exc)
    try:
        heard = _handshake(ser, cfg.drivers.arduino)
    finally:
        ser.close()
    if not heard.frames:
        return _silent(path, heard)
    return _verdict(path, heard, cfg)
