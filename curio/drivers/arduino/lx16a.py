"""LX-16A bus-servo packets (pure: no I/O). Spec: ``shared/reference/hardware.md`` §4.

Packet::

    55 55 | ID | LEN | CMD | params (LEN − 3 bytes, little-endian) | CHK

* ``LEN`` = number of params + 3; the whole packet is ``LEN + 3`` bytes.
* ``CHK = ~(ID + LEN + CMD + Σparams) & 0xFF`` (the header is excluded).
* ID 254 (0xFE) is the broadcast id: every servo obeys and none replies (except ID_READ).

Units: positions in LX-16A units (0..1000 = 0..240°, 0.24° per unit; motor-mode positions are
signed and run about −194..1194), duty −1000..1000, times in ms, voltages in mV.

Used by the Arduino emulator's servo bus and by setup tools (SERVO_RAW); the firmware has the
same code in C++ (``firmware/curio_base/src/lx16a.{h,cpp}``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

__all__ = [
    "BROADCAST_ID",
    "Cmd",
    "Lx16aPacket",
    "PacketParser",
    "angle_offset_adjust",
    "build",
    "checksum",
    "motor_mode",
    "move_time",
    "position_mode",
    "position_reply",
    "read_request",
    "vin_reply",
]

HEADER = b"\x55\x55"
BROADCAST_ID = 0xFE
MAX_ID = 253


class Cmd(IntEnum):
    """LX-16A command numbers (hardware.md §4.3)."""

    MOVE_TIME_WRITE = 1
    MOVE_TIME_READ = 2
    MOVE_TIME_WAIT_WRITE = 7
    MOVE_TIME_WAIT_READ = 8
    MOVE_START = 11
    MOVE_STOP = 12
    ID_WRITE = 13
    ID_READ = 14
    ANGLE_OFFSET_ADJUST = 17
    ANGLE_OFFSET_WRITE = 18
    ANGLE_OFFSET_READ = 19
    ANGLE_LIMIT_WRITE = 20
    ANGLE_LIMIT_READ = 21
    VIN_LIMIT_WRITE = 22
    VIN_LIMIT_READ = 23
    TEMP_MAX_LIMIT_WRITE = 24
    TEMP_MAX_LIMIT_READ = 25
    TEMP_READ = 26
    VIN_READ = 27
    POS_READ = 28
    OR_MOTOR_MODE_WRITE = 29
    OR_MOTOR_MODE_READ = 30
    LOAD_OR_UNLOAD_WRITE = 31
    LOAD_OR_UNLOAD_READ = 32
    LED_CTRL_WRITE = 33
    LED_CTRL_READ = 34
    LED_ERROR_WRITE = 35
    LED_ERROR_READ = 36


# Param byte counts of the reply to each read command.
REPLY_PARAMS: dict[int, int] = {
    Cmd.MOVE_TIME_READ: 4, Cmd.MOVE_TIME_WAIT_READ: 4, Cmd.ID_READ: 1,
    Cmd.ANGLE_OFFSET_READ: 1, Cmd.ANGLE_LIMIT_READ: 4, Cmd.VIN_LIMIT_READ: 4,
    Cmd.TEMP_MAX_LIMIT_READ: 1, Cmd.TEMP_READ: 1, Cmd.VIN_READ: 2, Cmd.POS_READ: 2,
    Cmd.OR_MOTOR_MODE_READ: 4, Cmd.LOAD_OR_UNLOAD_READ: 1, Cmd.LED_CTRL_READ: 1,
    Cmd.LED_ERROR_READ: 1,
}


def checksum(servo_id: int, length: int, cmd: int, params: bytes) -> int:
    """The LX-16A checksum: the inverted low byte of ID + LEN + CMD + Σparams."""
    return (~(servo_id + length + cmd + sum(params))) & 0xFF


def build(servo_id: int, cmd: int, params: bytes = b"") -> bytes:
    """Build one packet.

    Raises:
        ValueError: id outside 0..254 or more than 252 param bytes.
    """
    if not 0 <= servo_id <= BROADCAST_ID:
        raise ValueError(f"servo id {servo_id} outside 0..253 (254 = broadcast)")
    if len(params) > 252:
        raise ValueError("an LX-16A packet carries at most 252 param bytes")
    length = len(params) + 3
    return HEADER + bytes((servo_id, length, cmd)) + params + bytes(
        (checksum(servo_id, length, cmd, params),))


def read_request(servo_id: int, cmd: int) -> bytes:
    """A read request (no params), e.g. ``read_request(11, Cmd.POS_READ)``."""
    return build(servo_id, cmd)


def motor_mode(servo_id: int, duty: int) -> bytes:
    """SERVO_OR_MOTOR_MODE_WRITE in motor mode at ``duty`` (clamped to −1000..1000)."""
    duty = max(-1000, min(1000, int(duty)))
    return build(servo_id, Cmd.OR_MOTOR_MODE_WRITE, struct.pack("<BBh", 1, 0, duty))


def position_mode(servo_id: int) -> bytes:
    """SERVO_OR_MOTOR_MODE_WRITE in position (servo) mode."""
    return build(servo_id, Cmd.OR_MOTOR_MODE_WRITE, struct.pack("<BBh", 0, 0, 0))


def move_time(servo_id: int, position: int, time_ms: int) -> bytes:
    """SERVO_MOVE_TIME_WRITE: go to ``position`` (0..1000) in ``time_ms`` (0..30000)."""
    position = max(0, min(1000, int(position)))
    time_ms = max(0, min(30000, int(time_ms)))
    return build(servo_id, Cmd.MOVE_TIME_WRITE, struct.pack("<HH", position, time_ms))


def angle_offset_adjust(servo_id: int, trim: int) -> bytes:
    """SERVO_ANGLE_OFFSET_ADJUST by ``trim`` units (−125..125, not saved)."""
    if not -125 <= trim <= 125:
        raise ValueError(f"trim {trim} outside −125..125 LX-16A units")
    return build(servo_id, Cmd.ANGLE_OFFSET_ADJUST, struct.pack("<b", trim))


def position_reply(servo_id: int, position: int) -> bytes:
    """The servo's reply to POS_READ (signed position)."""
    return build(servo_id, Cmd.POS_READ, struct.pack("<h", position))


def vin_reply(servo_id: int, vin_mv: int) -> bytes:
    """The servo's reply to VIN_READ (supply in mV)."""
    return build(servo_id, Cmd.VIN_READ, struct.pack("<H", vin_mv))


@dataclass(frozen=True, slots=True)
class Lx16aPacket:
    """One parsed packet: servo id, command and param bytes."""

    servo_id: int
    cmd: int
    params: bytes

    def i16(self, offset: int = 0) -> int:
        """A signed 16-bit param at ``offset``."""
        return int(struct.unpack_from("<h", self.params, offset)[0])

    def u16(self, offset: int = 0) -> int:
        """An unsigned 16-bit param at ``offset``."""
        return int(struct.unpack_from("<H", self.params, offset)[0])


@dataclass
class PacketParser:
    """Incremental packet parser that tolerates echoes and stray bytes.

    It hunts for ``55 55``, checks the length (3..255) and checksum, and on failure restarts
    one byte later. ``bad_checksums`` and ``garbage_bytes`` count what it threw away.
    """

    bad_checksums: int = 0
    garbage_bytes: int = 0
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[Lx16aPacket]:
        """Add bytes; return every complete packet with a correct checksum."""
        buf = self._buf
        buf += data
        out: list[Lx16aPacket] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                keep = 1 if buf.endswith(b"\x55") else 0
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return out
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < 4:
                return out
            length = buf[3]
            if length < 3:
                self.garbage_bytes += 1
                del buf[:1]
                continue
            total = length + 3
            if len(buf) < total:
                return out
            servo_id, cmd = buf[2], buf[4]
            params = bytes(buf[5:total - 1])
            if buf[total - 1] != checksum(servo_id, length, cmd, params):
                self.bad_checksums += 1
                del buf[:1]
                continue
            out.append(Lx16aPacket(servo_id, cmd, params))
            del buf[:total]


COUNTS_PER_TURN = 1500  # Curio's model of one turn in motor mode (360° / 0.24°)
DEAD_ZONE_START = 1190  # mod 1500: readings are not valid from here ...
DEAD_ZONE_END = 1306  # ... up to here (raw −194)


def reading_from_count(count: float) -> int:
    """The raw POS_READ value a spinning LX-16A reports at continuous ``count`` (1500 a turn).

    Valid band: counts 0..1189 read as themselves and 1306..1499 as −194..−1; inside the dead
    zone the reading sticks near 1194 and drifts back a little (hardware.md §4.5).
    """
    c = int(count) % COUNTS_PER_TURN
    if c < DEAD_ZONE_START:
        return c
    if c >= DEAD_ZONE_END:
        return c - COUNTS_PER_TURN
    return 1194 - (c - DEAD_ZONE_START) // 10
