"""The Pi ↔ Arduino Mega framed binary protocol (pure: bytes in, values out; no I/O).

Specification: ``shared/reference/hardware.md`` §3.2, mirrored byte for byte by the firmware
(``firmware/curio_base/src/protocol.{h,cpp}``).

Frame (all multi-byte fields little-endian)::

    CA FE | LEN | SEQ | MSG_ID | payload (LEN bytes, 0..200) | CRC16 (u16 LE)

* ``CA FE`` are the sync bytes; ``SEQ`` is a u8 counter per direction that wraps;
  ``MSG_ID`` is 0x01–0x3F host→MCU and 0x80–0xBF MCU→host.
* The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0; check value
  0x29B1 for ``b"123456789"``) over LEN, SEQ, MSG_ID and the payload.
* A frame is ``LEN + 7`` bytes long.

:class:`FrameDecoder` is an incremental receiver: it hunts for ``CA FE``, rejects LEN > 200,
checks the CRC, and after any failure restarts the hunt at the byte after the ``CA`` that failed
(never after the whole would-be frame), so one corrupt or truncated frame costs at most itself.
It counts CRC errors, rejected lengths, discarded garbage bytes and resynchronisations.

Each message is a frozen dataclass with ``pack() -> bytes`` (the payload) and a classmethod
``unpack(payload)``; :func:`encode` builds a whole frame and :func:`decode_message` turns a
:class:`Frame` into its message. Units: durations in ms (as on the wire), voltages in mV,
servo values in LX-16A units (duty −1000..1000, position 0..1000 = 0..240°).
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import ClassVar, Protocol

__all__ = [
    "DEFAULT_STEER_IDS",
    "DEFAULT_WHEEL_IDS",
    "MAX_PAYLOAD",
    "PROTO_VERSION",
    "SYNC0",
    "SYNC1",
    "Ack",
    "AckStatus",
    "Arm",
    "Battery",
    "Estop",
    "Fault",
    "Frame",
    "FrameDecoder",
    "GetInfo",
    "Heartbeat",
    "Info",
    "Log",
    "McuState",
    "Message",
    "MsgId",
    "ProtocolError",
    "RcChannels",
    "ServoCmd",
    "ServoPos",
    "ServoRaw",
    "ServoRawReply",
    "ServoStatus",
    "ServoStatusEntry",
    "SetConfig",
    "State",
    "crc16",
    "decode_message",
    "encode",
    "encode_frame",
]

SYNC0 = 0xCA
SYNC1 = 0xFE
MAX_PAYLOAD = 200
HEADER_SIZE = 5  # sync (2) + LEN + SEQ + MSG_ID
FRAME_OVERHEAD = 7  # header + CRC
PROTO_VERSION = 1
STEER_UNCHANGED = 0xFFFF  # SERVO_CMD steering value: leave this servo where it is
ADC_NOT_FITTED = 0xFFFF  # BATTERY adc_mV: no divider on A0
RC_NEW = 0x01  # RC.flags: a new receiver frame since the last report
RC_FAILSAFE = 0x02  # the receiver is in failsafe (SUMD status 0x81)
RC_LOST = 0x04  # no valid receiver frame for 100 ms
RC_SUMH = 0x08

DEFAULT_WHEEL_IDS: tuple[int, ...] = (11, 12, 13, 21, 22, 23)  # FL, ML, BL, FR, MR, BR
DEFAULT_STEER_IDS: tuple[int, ...] = (111, 131, 211, 231)  # FL, BL, FR, BR


class ProtocolError(ValueError):
    """A frame or payload that does not follow the protocol (the message says what is wrong)."""


class MsgId(IntEnum):
    """Message identifiers: 0x01–0x3F host→MCU, 0x80–0xBF MCU→host."""

    SET_CONFIG = 0x01
    SERVO_CMD = 0x02
    ESTOP = 0x03
    ARM = 0x04
    HEARTBEAT = 0x05
    GET_INFO = 0x06
    SERVO_RAW = 0x07
    ACK = 0x80
    SERVO_POS = 0x81
    SERVO_STATUS = 0x82
    RC = 0x83
    STATE = 0x84
    BATTERY = 0x85
    INFO = 0x86
    SERVO_RAW_REPLY = 0x87
    LOG = 0x8F


class McuState(IntEnum):
    """The firmware's state machine (``STATE.state``)."""

    BOOT = 0
    DISARMED = 1
    ARMED = 2
    TIMEOUT = 3
    ESTOP = 4


class Fault(IntEnum):
    """Bits of ``STATE.faults``."""

    MOTION_WATCHDOG = 1 << 0  # no SERVO_CMD for cmd_timeout_ms: wheels stopped
    SERVO_READ = 1 << 1  # a servo read failed in the last sweep
    RC_LOST = 1 << 2
    UART_OVERRUN = 1 << 3
    DEFAULT_CONFIG = 1 << 4  # running the built-in config: the host must send SET_CONFIG
    RESET_WATCHDOG = 1 << 5  # the MCU came up from a watchdog or brown-out reset


class AckStatus(IntEnum):
    """``ACK.status`` values."""

    OK = 0
    BAD_LENGTH = 1
    BAD_VALUE = 2
    BUSY = 3
    UNKNOWN_ID = 4
    WRONG_STATE = 5


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


@dataclass(frozen=True, slots=True)
class Frame:
    """One received frame: its sequence number, message id and raw payload."""

    seq: int
    msg_id: int
    payload: bytes


def encode_frame(msg_id: int, seq: int, payload: bytes = b"") -> bytes:
    """Build the bytes of one frame.

    Raises:
        ProtocolError: payload longer than 200 bytes, or seq / msg_id outside 0..255.
    """
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f"payload of {len(payload)} bytes; at most {MAX_PAYLOAD} allowed")
    if not 0 <= seq <= 0xFF or not 0 <= msg_id <= 0xFF:
        raise ProtocolError(f"seq {seq} and msg_id {msg_id} must be 0..255")
    body = bytes((len(payload), seq, msg_id)) + payload
    return bytes((SYNC0, SYNC1)) + body + struct.pack("<H", crc16(body))


# --- messages -------------------------------------------------------------------------------


class Message(Protocol):
    """What every message class provides."""

    MSG_ID: ClassVar[MsgId]

    def pack(self) -> bytes:
        """The payload bytes."""
        ...


def _check_len(name: str, payload: bytes, size: int) -> None:
    if len(payload) != size:
        raise ProtocolError(f"{name} payload must be {size} bytes, got {len(payload)}")


def _u8(name: str, value: int) -> int:
    if not 0 <= value <= 0xFF:
        raise ProtocolError(f"{name} = {value} does not fit a u8 (0..255)")
    return value


@dataclass(frozen=True, slots=True)
class SetConfig:
    """SET_CONFIG (host→MCU, 22 bytes): servo ids, trims, timing. Answered with ACK.

    Attributes:
        wheel_ids: LX-16A ids FL, ML, BL, FR, MR, BR.
        steer_ids: LX-16A ids FL, BL, FR, BR.
        steer_trim: per steering servo trim, LX-16A units (−125..125, 0.24° each).
        cmd_timeout_ms: motion watchdog: wheels stop after this long without SERVO_CMD.
        pos_rate_hz: SERVO_POS rate (1..40).
        status_rate_hz: SERVO_STATUS and BATTERY rate (1..10).
        steer_move_ms: move time given to the steering servos.
        flags: bit0 persist trim, bit1 RC enable, bit2 RC type (0 SUMD, 1 PWM).
    """

    MSG_ID: ClassVar[MsgId] = MsgId.SET_CONFIG
    SIZE: ClassVar[int] = 22
    FMT: ClassVar[str] = "<B6B4B4bHBBHB"

    wheel_ids: tuple[int, ...] = DEFAULT_WHEEL_IDS
    steer_ids: tuple[int, ...] = DEFAULT_STEER_IDS
    steer_trim: tuple[int, ...] = (0, 0, 0, 0)
    cmd_timeout_ms: int = 500
    pos_rate_hz: int = 30
    status_rate_hz: int = 1
    steer_move_ms: int = 50
    flags: int = 0
    proto_ver: int = PROTO_VERSION

    def pack(self) -> bytes:
        """The payload bytes."""
        if len(self.wheel_ids) != 6 or len(self.steer_ids) != 4 or len(self.steer_trim) != 4:
            raise ProtocolError("SET_CONFIG needs 6 wheel ids, 4 steering ids and 4 trims")
        try:
            return struct.pack(self.FMT, self.proto_ver, *self.wheel_ids, *self.steer_ids,
                               *self.steer_trim, self.cmd_timeout_ms, self.pos_rate_hz,
                               self.status_rate_hz, self.steer_move_ms, self.flags)
        except struct.error as exc:
            raise ProtocolError(f"SET_CONFIG field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> SetConfig:
        """Parse the payload."""
        _check_len("SET_CONFIG", payload, cls.SIZE)
        v = struct.unpack(cls.FMT, payload)
        return cls(wheel_ids=tuple(v[1:7]), steer_ids=tuple(v[7:11]), steer_trim=tuple(v[11:15]),
                   cmd_timeout_ms=v[15], pos_rate_hz=v[16], status_rate_hz=v[17],
                   steer_move_ms=v[18], flags=v[19], proto_ver=v[0])

    def problems(self) -> list[str]:
        """What the firmware would refuse (empty when valid); mirrors ``Config::validate``."""
        out: list[str] = []
        if self.proto_ver != PROTO_VERSION:
            out.append(f"proto_ver {self.proto_ver} (this firmware speaks {PROTO_VERSION})")
        ids = [*self.wheel_ids, *self.steer_ids]
        if any(not 0 <= i <= 253 for i in ids) or len(set(ids)) != len(ids):
            out.append("servo ids must be distinct and 0..253")
        if any(not -125 <= t <= 125 for t in self.steer_trim):
            out.append("steer_trim must be −125..125")
        if not 50 <= self.cmd_timeout_ms <= 5000:
            out.append("cmd_timeout_ms must be 50..5000")
        if not 1 <= self.pos_rate_hz <= 40:
            out.append("pos_rate_hz must be 1..40")
        if not 1 <= self.status_rate_hz <= 10:
            out.append("status_rate_hz must be 1..10")
        if not 0 <= self.steer_move_ms <= 30000:
            out.append("steer_move_ms must be 0..30000")
        return out


@dataclass(frozen=True, slots=True)
class ServoCmd:
    """SERVO_CMD (host→MCU, 21 bytes): six wheel duties, four steering positions, flags.

    Attributes:
        wheel_duty: LX-16A motor duties −1000..1000 (clamped by the MCU), FL ML BL FR MR BR.
        steer_pos: LX-16A positions 0..1000, FL BL FR BR; 0xFFFF leaves a servo unchanged.
        flags: bit0 = this command intends motion.
    """

    MSG_ID: ClassVar[MsgId] = MsgId.SERVO_CMD
    SIZE: ClassVar[int] = 21
    FMT: ClassVar[str] = "<6h4HB"

    wheel_duty: tuple[int, ...]
    steer_pos: tuple[int, ...]
    flags: int = 0

    def pack(self) -> bytes:
        """The payload bytes."""
        if len(self.wheel_duty) != 6 or len(self.steer_pos) != 4:
            raise ProtocolError("SERVO_CMD needs 6 wheel duties and 4 steering positions")
        try:
            return struct.pack(self.FMT, *self.wheel_duty, *self.steer_pos, self.flags)
        except struct.error as exc:
            raise ProtocolError(f"SERVO_CMD field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> ServoCmd:
        """Parse the payload."""
        _check_len("SERVO_CMD", payload, cls.SIZE)
        v = struct.unpack(cls.FMT, payload)
        return cls(wheel_duty=tuple(v[0:6]), steer_pos=tuple(v[6:10]), flags=v[10])


@dataclass(frozen=True, slots=True)
class Estop:
    """ESTOP (host→MCU, empty): stop every wheel now and latch the ESTOP state until ARM."""

    MSG_ID: ClassVar[MsgId] = MsgId.ESTOP

    def pack(self) -> bytes:
        """The payload bytes (none)."""
        return b""

    @classmethod
    def unpack(cls, payload: bytes) -> Estop:
        """Parse the payload."""
        _check_len("ESTOP", payload, 0)
        return cls()


@dataclass(frozen=True, slots=True)
class Arm:
    """ARM (host→MCU, 1 byte): 1 = arm (leaves DISARMED, TIMEOUT or ESTOP), 0 = disarm."""

    MSG_ID: ClassVar[MsgId] = MsgId.ARM

    arm: bool = True

    def pack(self) -> bytes:
        """The payload bytes."""
        return bytes((1 if self.arm else 0,))

    @classmethod
    def unpack(cls, payload: bytes) -> Arm:
        """Parse the payload (any value other than 0 or 1 is refused)."""
        _check_len("ARM", payload, 1)
        if payload[0] > 1:
            raise ProtocolError(f"ARM takes 0 or 1, got {payload[0]}")
        return cls(arm=payload[0] == 1)


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """HEARTBEAT (host→MCU, 4 bytes): host time in ms (u32, wraps); echoed in STATE."""

    MSG_ID: ClassVar[MsgId] = MsgId.HEARTBEAT

    host_ms: int

    def pack(self) -> bytes:
        """The payload bytes."""
        return struct.pack("<I", self.host_ms & 0xFFFFFFFF)

    @classmethod
    def unpack(cls, payload: bytes) -> Heartbeat:
        """Parse the payload."""
        _check_len("HEARTBEAT", payload, 4)
        return cls(host_ms=struct.unpack("<I", payload)[0])


@dataclass(frozen=True, slots=True)
class GetInfo:
    """GET_INFO (host→MCU, empty): asks for INFO."""

    MSG_ID: ClassVar[MsgId] = MsgId.GET_INFO

    def pack(self) -> bytes:
        """The payload bytes (none)."""
        return b""

    @classmethod
    def unpack(cls, payload: bytes) -> GetInfo:
        """Parse the payload."""
        _check_len("GET_INFO", payload, 0)
        return cls()


@dataclass(frozen=True, slots=True)
class ServoRaw:
    """SERVO_RAW (host→MCU): one complete LX-16A frame to forward (setup tools; not ARMED)."""

    MSG_ID: ClassVar[MsgId] = MsgId.SERVO_RAW

    data: bytes

    def pack(self) -> bytes:
        """The payload bytes."""
        if len(self.data) > MAX_PAYLOAD - 1:
            raise ProtocolError(f"SERVO_RAW carries at most {MAX_PAYLOAD - 1} bytes")
        return bytes((len(self.data),)) + self.data

    @classmethod
    def unpack(cls, payload: bytes) -> ServoRaw:
        """Parse the payload."""
        if not payload or payload[0] != len(payload) - 1:
            raise ProtocolError("SERVO_RAW payload must be n followed by n bytes")
        return cls(data=bytes(payload[1:]))


@dataclass(frozen=True, slots=True)
class Ack:
    """ACK (MCU→host, 3 bytes): which frame it answers and how it went (:class:`AckStatus`)."""

    MSG_ID: ClassVar[MsgId] = MsgId.ACK

    acked_seq: int
    acked_id: int
    status: int = AckStatus.OK

    def pack(self) -> bytes:
        """The payload bytes."""
        return bytes((_u8("acked_seq", self.acked_seq), _u8("acked_id", self.acked_id),
                      _u8("status", self.status)))

    @classmethod
    def unpack(cls, payload: bytes) -> Ack:
        """Parse the payload."""
        _check_len("ACK", payload, 3)
        return cls(acked_seq=payload[0], acked_id=payload[1], status=payload[2])


@dataclass(frozen=True, slots=True)
class ServoPos:
    """SERVO_POS (MCU→host, 36 bytes): one sweep of position reads.

    Attributes:
        t_ms: MCU millis at the start of the sweep (u32, wraps).
        valid_mask: bit i set = servo i read OK (wheels 0–5, then steering 0–3); a failed read
            repeats the previous value.
        wheel_pos: raw signed LX-16A positions (about −194..1194 while spinning).
        steer_pos: raw LX-16A positions 0..1000.
        dt_ms: offset of each read from ``t_ms``, ms.
    """

    MSG_ID: ClassVar[MsgId] = MsgId.SERVO_POS
    SIZE: ClassVar[int] = 36
    FMT: ClassVar[str] = "<IH6h4h10B"

    t_ms: int
    valid_mask: int
    wheel_pos: tuple[int, ...]
    steer_pos: tuple[int, ...]
    dt_ms: tuple[int, ...] = (0,) * 10

    def pack(self) -> bytes:
        """The payload bytes."""
        try:
            return struct.pack(self.FMT, self.t_ms & 0xFFFFFFFF, self.valid_mask,
                               *self.wheel_pos, *self.steer_pos, *self.dt_ms)
        except struct.error as exc:
            raise ProtocolError(f"SERVO_POS field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> ServoPos:
        """Parse the payload."""
        _check_len("SERVO_POS", payload, cls.SIZE)
        v = struct.unpack(cls.FMT, payload)
        return cls(t_ms=v[0], valid_mask=v[1], wheel_pos=tuple(v[2:8]),
                   steer_pos=tuple(v[8:12]), dt_ms=tuple(v[12:22]))

    def wheel_valid(self, i: int) -> bool:
        """Whether wheel ``i`` (0..5) was read in this sweep."""
        return bool(self.valid_mask >> i & 1)


@dataclass(frozen=True, slots=True)
class ServoStatusEntry:
    """One servo's slow status: id, supply mV, temperature °C, mode (0 position, 1 motor,
    0xFF unknown), LED error bits (0xFF unknown), saturating communication error count."""

    servo_id: int
    vin_mv: int
    temp_c: int = 0xFF
    mode: int = 0xFF
    led_error: int = 0xFF
    comm_errs: int = 0

    FMT: ClassVar[str] = "<BHBBBB"


@dataclass(frozen=True, slots=True)
class ServoStatus:
    """SERVO_STATUS (MCU→host, 74 bytes): t_ms and ten :class:`ServoStatusEntry`."""

    MSG_ID: ClassVar[MsgId] = MsgId.SERVO_STATUS
    SIZE: ClassVar[int] = 74

    t_ms: int
    servos: tuple[ServoStatusEntry, ...]

    def pack(self) -> bytes:
        """The payload bytes."""
        if len(self.servos) != 10:
            raise ProtocolError("SERVO_STATUS carries exactly 10 servos")
        out = struct.pack("<I", self.t_ms & 0xFFFFFFFF)
        try:
            for s in self.servos:
                out += struct.pack(ServoStatusEntry.FMT, s.servo_id, s.vin_mv, s.temp_c, s.mode,
                                   s.led_error, s.comm_errs)
        except struct.error as exc:
            raise ProtocolError(f"SERVO_STATUS field out of range: {exc}") from None
        return out

    @classmethod
    def unpack(cls, payload: bytes) -> ServoStatus:
        """Parse the payload."""
        _check_len("SERVO_STATUS", payload, cls.SIZE)
        t_ms = struct.unpack_from("<I", payload)[0]
        servos = tuple(ServoStatusEntry(*struct.unpack_from(ServoStatusEntry.FMT, payload,
                                                            4 + 7 * i)) for i in range(10))
        return cls(t_ms=t_ms, servos=servos)


@dataclass(frozen=True, slots=True)
class RcChannels:
    """RC (MCU→host): receiver channels in µs, raw receiver order.

    Attributes:
        flags: bit0 new frame, bit1 failsafe, bit2 signal lost, bit3 SUMH.
        frame_counter: u8 count of receiver frames.
        channels_us: pulse widths, µs (up to 16).
    """

    MSG_ID: ClassVar[MsgId] = MsgId.RC

    t_ms: int
    flags: int
    frame_counter: int
    channels_us: tuple[int, ...]

    def pack(self) -> bytes:
        """The payload bytes."""
        if len(self.channels_us) > 32:
            raise ProtocolError("RC carries at most 32 channels")
        try:
            return struct.pack(f"<IBBB{len(self.channels_us)}H", self.t_ms & 0xFFFFFFFF,
                               self.flags, self.frame_counter, len(self.channels_us),
                               *self.channels_us)
        except struct.error as exc:
            raise ProtocolError(f"RC field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> RcChannels:
        """Parse the payload."""
        if len(payload) < 7 or len(payload) != 7 + 2 * payload[6]:
            raise ProtocolError(f"RC payload of {len(payload)} bytes does not match its count")
        t_ms, flags, counter, n = struct.unpack_from("<IBBB", payload)
        return cls(t_ms=t_ms, flags=flags, frame_counter=counter,
                   channels_us=struct.unpack_from(f"<{n}H", payload, 7))


@dataclass(frozen=True, slots=True)
class State:
    """STATE (MCU→host, 18 bytes): 10 Hz and on every change.

    Attributes:
        t_ms: MCU millis.
        state: :class:`McuState` value.
        faults: :class:`Fault` bits.
        last_host_ms: the last HEARTBEAT's host_ms (for the round-trip time).
        rx_crc_err: CRC errors the MCU has counted (u16, wraps).
        rx_ok: frames the MCU has accepted (u16, wraps).
        loop_max_us: the slowest main-loop iteration since the last report, µs.
        reset_cause: MCUSR at boot (bit0 power-on, bit1 external, bit2 brown-out, bit3 watchdog).
    """

    MSG_ID: ClassVar[MsgId] = MsgId.STATE
    SIZE: ClassVar[int] = 18
    FMT: ClassVar[str] = "<IBHIHHHB"

    t_ms: int
    state: int
    faults: int = 0
    last_host_ms: int = 0
    rx_crc_err: int = 0
    rx_ok: int = 0
    loop_max_us: int = 0
    reset_cause: int = 0

    def pack(self) -> bytes:
        """The payload bytes."""
        try:
            return struct.pack(self.FMT, self.t_ms & 0xFFFFFFFF, self.state, self.faults,
                               self.last_host_ms & 0xFFFFFFFF, self.rx_crc_err & 0xFFFF,
                               self.rx_ok & 0xFFFF, self.loop_max_us, self.reset_cause)
        except struct.error as exc:
            raise ProtocolError(f"STATE field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> State:
        """Parse the payload."""
        _check_len("STATE", payload, cls.SIZE)
        return cls(*struct.unpack(cls.FMT, payload))


@dataclass(frozen=True, slots=True)
class Battery:
    """BATTERY (MCU→host, 4 bytes): median servo supply mV; A0 divider mV (0xFFFF = none)."""

    MSG_ID: ClassVar[MsgId] = MsgId.BATTERY

    servo_vin_mv: int
    adc_mv: int = ADC_NOT_FITTED

    def pack(self) -> bytes:
        """The payload bytes."""
        try:
            return struct.pack("<HH", self.servo_vin_mv, self.adc_mv)
        except struct.error as exc:
            raise ProtocolError(f"BATTERY field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> Battery:
        """Parse the payload."""
        _check_len("BATTERY", payload, 4)
        return cls(*struct.unpack("<HH", payload))


@dataclass(frozen=True, slots=True)
class Info:
    """INFO (MCU→host, 9 bytes): protocol and firmware versions, build, config CRC."""

    MSG_ID: ClassVar[MsgId] = MsgId.INFO
    FMT: ClassVar[str] = "<BBBIH"

    proto_ver: int
    fw_major: int
    fw_minor: int
    build: int = 0
    config_crc: int = 0

    def pack(self) -> bytes:
        """The payload bytes."""
        try:
            return struct.pack(self.FMT, self.proto_ver, self.fw_major, self.fw_minor,
                               self.build, self.config_crc)
        except struct.error as exc:
            raise ProtocolError(f"INFO field out of range: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes) -> Info:
        """Parse the payload."""
        _check_len("INFO", payload, 9)
        return cls(*struct.unpack(cls.FMT, payload))


@dataclass(frozen=True, slots=True)
class ServoRawReply:
    """SERVO_RAW_REPLY (MCU→host): status (0 OK, 1 no reply) and the raw reply bytes."""

    MSG_ID: ClassVar[MsgId] = MsgId.SERVO_RAW_REPLY

    status: int
    data: bytes = b""

    def pack(self) -> bytes:
        """The payload bytes."""
        return bytes((_u8("status", self.status), len(self.data))) + self.data

    @classmethod
    def unpack(cls, payload: bytes) -> ServoRawReply:
        """Parse the payload."""
        if len(payload) < 2 or payload[1] != len(payload) - 2:
            raise ProtocolError("SERVO_RAW_REPLY payload must be status, n, n bytes")
        return cls(status=payload[0], data=bytes(payload[2:]))


@dataclass(frozen=True, slots=True)
class Log:
    """LOG (MCU→host): a level (0 debug .. 3 error) and ASCII text."""

    MSG_ID: ClassVar[MsgId] = MsgId.LOG

    level: int
    text: str

    def pack(self) -> bytes:
        """The payload bytes."""
        return bytes((_u8("level", self.level),)) + self.text.encode("ascii", "replace")

    @classmethod
    def unpack(cls, payload: bytes) -> Log:
        """Parse the payload."""
        if not payload:
            raise ProtocolError("LOG payload needs at least the level byte")
        return cls(level=payload[0], text=payload[1:].decode("ascii", "replace"))


_MESSAGE_TYPES: dict[int, type[object]] = {
    cls.MSG_ID: cls
    for cls in (SetConfig, ServoCmd, Estop, Arm, Heartbeat, GetInfo, ServoRaw, Ack, ServoPos,
                ServoStatus, RcChannels, State, Battery, Info, ServoRawReply, Log)
}


def encode(msg: Message, seq: int) -> bytes:
    """Build the frame carrying ``msg`` with sequence number ``seq`` (0..255)."""
    return encode_frame(msg.MSG_ID, seq, msg.pack())


def decode_message(frame: Frame) -> Message:
    """Turn a frame into its message.

    Raises:
        ProtocolError: unknown message id, or a payload of the wrong size or content.
    """
    cls = _MESSAGE_TYPES.get(frame.msg_id)
    if cls is None:
        raise ProtocolError(f"unknown message id 0x{frame.msg_id:02X}")
    msg: Message = cls.unpack(frame.payload)  # type: ignore[attr-defined]
    return msg


# --- incremental decoder ----------------------------------------------------------------------


@dataclass
class DecoderStats:
    """Receive counters of a :class:`FrameDecoder`.

    Attributes:
        frames: frames that passed the CRC.
        crc_errors: would-be frames whose CRC did not match.
        length_errors: headers with LEN > 200.
        garbage_bytes: bytes discarded while hunting for sync.
        resyncs: times the decoder had to discard bytes to find the next frame.
    """

    frames: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    garbage_bytes: int = 0
    resyncs: int = 0


@dataclass
class FrameDecoder:
    """Incremental frame receiver: ``feed(chunk)`` returns the complete, CRC-checked frames.

    Bytes may arrive split anywhere, several frames per chunk, with garbage in between. After a
    CRC or length failure the hunt restarts at the byte after the failing ``CA``.
    """

    stats: DecoderStats = field(default_factory=DecoderStats)
    _buf: bytearray = field(default_factory=bytearray)
    _skipping: bool = False

    def reset(self) -> None:
        """Forget any partial frame (after a reconnect); counters are kept."""
        self._buf.clear()
        self._skipping = False

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def _discard(self, n: int) -> None:
        if n <= 0:
            return
        del self._buf[:n]
        self.stats.garbage_bytes += n
        if not self._skipping:
            self.stats.resyncs += 1
            self._skipping = True

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Add received bytes; return every complete valid frame, oldest first."""
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        while True:
            start = buf.find(b"\xca\xfe")
            if start < 0:
                # Keep a trailing CA: it may be the first half of the next sync.
                self._discard(len(buf) - 1 if buf.endswith(b"\xca") else len(buf))
                return frames
            self._discard(start)
            if len(buf) < HEADER_SIZE:
                return frames
            length = buf[2]
            if length > MAX_PAYLOAD:
                self.stats.length_errors += 1
                self._discard(1)
                continue
            total = length + FRAME_OVERHEAD
            if len(buf) < total:
                return frames
            body = bytes(buf[2:HEADER_SIZE + length])
            (crc,) = struct.unpack_from("<H", buf, HEADER_SIZE + length)
            if crc != crc16(body):
                self.stats.crc_errors += 1
                self._discard(1)
                continue
            frames.append(Frame(seq=body[1], msg_id=body[2], payload=body[3:]))
            del buf[:total]
            self._skipping = False
            self.stats.frames += 1
