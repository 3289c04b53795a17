"""RPLidar A1 serial protocol: requests, response descriptors, measurement nodes (pure; no I/O).

Everything here turns bytes into values and values into bytes (hardware.md §5):

* requests ``A5 cmd`` (plus ``size payload xor`` when ``cmd & 0x80``), built by
  :func:`encode_request` and parsed on the device side by :class:`RequestParser`;
* 7-byte response descriptors ``A5 5A len(30 bit)|mode(2 bit) type``;
* GET_INFO (20 bytes) and GET_HEALTH (3 bytes, error code little-endian) payloads;
* the standard 5-byte measurement node with its start flag ``S``, inverse start flag ``!S`` and
  check bit ``C``: :func:`encode_node` / :func:`decode_node`, and :class:`NodeStreamDecoder`
  which decodes a byte stream vectorised and drops one byte at a time to resynchronise after
  bad bytes;
* :class:`ScanAssembler`, which cuts the node stream into revolutions at each ``S`` flag, and
  :func:`revolution_to_ranges`, which bins one revolution into a ``laser``-frame range array as
  ``rplidar_ros`` does: the laser angle is ``pi - raw`` (the raw angle grows clockwise seen from
  above, in degrees), so the frame matches Curio's URDF (hardware.md §5.5).

Units: raw angles in degrees (``q6`` = 1/64 degree), raw distances in millimetres (``q2`` =
1/4 mm), laser-frame angles in radians, ranges in metres.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import numpy.typing as npt

__all__ = [
    "DESCRIPTOR_LEN",
    "HEALTH_DESCRIPTOR",
    "INFO_DESCRIPTOR",
    "SCAN_DESCRIPTOR",
    "Cmd",
    "Descriptor",
    "DeviceInfo",
    "HealthStatus",
    "Node",
    "NodeBatch",
    "NodeStreamDecoder",
    "Request",
    "RequestParser",
    "ScanAssembler",
    "decode_node",
    "encode_descriptor",
    "encode_node",
    "encode_nodes",
    "encode_request",
    "laser_to_raw_deg",
    "parse_descriptor",
    "raw_to_laser_rad",
    "revolution_to_ranges",
]

SYNC1 = 0xA5
SYNC2 = 0x5A
DESCRIPTOR_LEN = 7
NODE_LEN = 5


class Cmd(IntEnum):
    """Request command bytes (the second byte after ``0xA5``)."""

    STOP = 0x25
    RESET = 0x40
    SCAN = 0x20
    FORCE_SCAN = 0x21
    GET_INFO = 0x50
    GET_HEALTH = 0x52
    GET_SAMPLERATE = 0x59
    EXPRESS_SCAN = 0x82
    SET_MOTOR_PWM = 0xF0
    GET_ACC_BOARD_FLAG = 0xFF


class HealthLevel(IntEnum):
    """GET_HEALTH status byte."""

    GOOD = 0
    WARNING = 1
    ERROR = 2  # protection stop: send RESET


# Data types of the response descriptors.
TYPE_SCAN = 0x81
TYPE_EXPRESS = 0x82
TYPE_INFO = 0x04
TYPE_HEALTH = 0x06
TYPE_SAMPLERATE = 0x15

MODE_SINGLE = 0
MODE_MULTI = 1


def encode_request(cmd: int, payload: bytes = b"") -> bytes:
    """Return the bytes of one request.

    Commands with bit 7 set carry ``payload`` with a size byte and an XOR checksum over every
    byte from ``0xA5`` through the last payload byte; the others must have no payload.

    Raises:
        ValueError: ``cmd`` is not a byte, or a payload was given to a command without one.
    """
    if not 0 <= cmd <= 0xFF:
        raise ValueError(f"command must be a byte 0..255, got {cmd}")
    if not cmd & 0x80:
        if payload:
            raise ValueError(f"command 0x{cmd:02X} takes no payload (bit 7 clear)")
        return bytes((SYNC1, cmd))
    if len(payload) > 255:
        raise ValueError(f"payload too long: {len(payload)} bytes (at most 255)")
    body = bytes((SYNC1, cmd, len(payload))) + payload
    checksum = 0
    for b in body:
        checksum ^= b
    return body + bytes((checksum,))


@dataclass(frozen=True, slots=True)
class Request:
    """A request as the device parsed it."""

    cmd: int
    payload: bytes = b""


@dataclass
class RequestParser:
    """Device-side request parser: feed bytes, get whole requests.

    Bytes before a ``0xA5`` are skipped; a payload request with a wrong checksum is dropped
    silently (as the device does) and counted in ``bad_checksums``.
    """

    _buf: bytearray = field(default_factory=bytearray)
    bad_checksums: int = 0
    skipped_bytes: int = 0

    def feed(self, data: bytes) -> list[Request]:
        """Add ``data``; return every complete request in it."""
        self._buf += data
        out: list[Request] = []
        buf = self._buf
        while buf:
            if buf[0] != SYNC1:
                self.skipped_bytes += 1
                del buf[0]
                continue
            if len(buf) < 2:
                break
            cmd = buf[1]
            if not cmd & 0x80:
                out.append(Request(cmd))
                del buf[:2]
                continue
            if len(buf) < 3:
                break
            size = buf[2]
            total = 3 + size + 1
            if len(buf) < total:
                break
            checksum = 0
            for b in buf[: total - 1]:
                checksum ^= b
            if checksum == buf[total - 1]:
                out.append(Request(cmd, bytes(buf[3 : 3 + size])))
            else:
                self.bad_checksums += 1
            del buf[:total]
        return out


@dataclass(frozen=True, slots=True)
class Descriptor:
    """A response descriptor: ``length`` bytes per response, ``mode``, ``data_type``."""

    length: int
    mode: int
    data_type: int


def encode_descriptor(length: int, mode: int, data_type: int) -> bytes:
    """Return the 7 descriptor bytes (length in bits 0–29, mode in bits 30–31, LE)."""
    if not 0 <= length < (1 << 30) or mode not in (0, 1, 2, 3):
        raise ValueError(f"bad descriptor length {length} or mode {mode}")
    return bytes((SYNC1, SYNC2)) + struct.pack("<IB", length | (mode << 30), data_type)


def parse_descriptor(data: bytes) -> Descriptor:
    """Parse 7 descriptor bytes.

    Raises:
        ValueError: not 7 bytes or not starting with ``A5 5A``.
    """
    if len(data) != DESCRIPTOR_LEN:
        raise ValueError(f"a descriptor is 7 bytes, got {len(data)}")
    if data[0] != SYNC1 or data[1] != SYNC2:
        raise ValueError(f"a descriptor starts with A5 5A, got {data[:2].hex(' ').upper()}")
    word, data_type = struct.unpack("<IB", data[2:])
    return Descriptor(word & 0x3FFFFFFF, word >> 30, data_type)


SCAN_DESCRIPTOR = encode_descriptor(5, MODE_MULTI, TYPE_SCAN)
INFO_DESCRIPTOR = encode_descriptor(20, MODE_SINGLE, TYPE_INFO)
HEALTH_DESCRIPTOR = encode_descriptor(3, MODE_SINGLE, TYPE_HEALTH)
SAMPLERATE_DESCRIPTOR = encode_descriptor(4, MODE_SINGLE, TYPE_SAMPLERATE)


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """GET_INFO answer: ``model`` = (major << 4) | sub-model (A1M8 = 0x18)."""

    model: int
    firmware_minor: int
    firmware_major: int
    hardware: int
    serial_number: bytes

    def encode(self) -> bytes:
        """The 20 payload bytes."""
        if len(self.serial_number) != 16:
            raise ValueError("the serial number is 16 bytes")
        return bytes((self.model, self.firmware_minor, self.firmware_major, self.hardware)) + (
            self.serial_number
        )

    @classmethod
    def decode(cls, data: bytes) -> DeviceInfo:
        """Parse the 20 payload bytes."""
        if len(data) != 20:
            raise ValueError(f"GET_INFO carries 20 bytes, got {len(data)}")
        return cls(data[0], data[1], data[2], data[3], bytes(data[4:20]))

    @property
    def model_name(self) -> str:
        """E.g. ``A1M8``."""
        return f"A{self.model >> 4}M{self.model & 0x0F}"

    @property
    def firmware(self) -> str:
        """E.g. ``1.29``."""
        return f"{self.firmware_major}.{self.firmware_minor:02d}"

    def describe(self) -> str:
        """One line: model, firmware, hardware, serial number."""
        return (
            f"RPLidar {self.model_name} firmware {self.firmware} hardware {self.hardware} "
            f"serial {self.serial_number.hex().upper()}"
        )


@dataclass(frozen=True, slots=True)
class HealthStatus:
    """GET_HEALTH answer: ``status`` 0 good, 1 warning, 2 error (protection stop)."""

    status: int
    error_code: int = 0

    def encode(self) -> bytes:
        """The 3 payload bytes (error code little-endian)."""
        return struct.pack("<BH", self.status, self.error_code)

    @classmethod
    def decode(cls, data: bytes) -> HealthStatus:
        """Parse the 3 payload bytes."""
        if len(data) != 3:
            raise ValueError(f"GET_HEALTH carries 3 bytes, got {len(data)}")
        status, code = struct.unpack("<BH", data)
        return cls(status, code)

    @property
    def name(self) -> str:
        """``good``, ``warning``, ``error`` or ``unknown(N)``."""
        names = {0: "good", 1: "warning", 2: "error"}
        return names.get(self.status, f"unknown({self.status})")


@dataclass(frozen=True, slots=True)
class Node:
    """One measurement: ``angle_deg`` clockwise from the raw 0°, ``distance_mm`` (0 = invalid)."""

    start: bool
    quality: int
    angle_deg: float
    distance_mm: float


def encode_node(start: bool, quality: int, angle_q6: int, distance_q2: int) -> bytes:
    """Return the 5 bytes of one node (angle in 1/64 degree, distance in 1/4 mm)."""
    if not 0 <= quality < 64:
        raise ValueError(f"quality is 6 bits (0..63), got {quality}")
    if not 0 <= angle_q6 < (1 << 15):
        raise ValueError(f"angle_q6 is 15 bits, got {angle_q6}")
    if not 0 <= distance_q2 < (1 << 16):
        raise ValueError(f"distance_q2 is 16 bits, got {distance_q2}")
    s = 1 if start else 0
    b0 = (quality << 2) | ((1 - s) << 1) | s
    b1 = ((angle_q6 & 0x7F) << 1) | 1
    b2 = angle_q6 >> 7
    return bytes((b0, b1, b2, distance_q2 & 0xFF, distance_q2 >> 8))


def encode_nodes(
    start: npt.NDArray[np.bool_],
    quality: npt.NDArray[np.integer],
    angle_q6: npt.NDArray[np.integer],
    distance_q2: npt.NDArray[np.integer],
) -> bytes:
    """Vectorised :func:`encode_node` for many nodes (values are clipped to their fields)."""
    n = len(angle_q6)
    out = np.empty((n, NODE_LEN), dtype=np.uint8)
    s = start.astype(np.uint8)
    q = np.clip(quality, 0, 63).astype(np.uint8)
    a = np.clip(angle_q6, 0, (1 << 15) - 1).astype(np.uint16)
    d = np.clip(distance_q2, 0, (1 << 16) - 1).astype(np.uint16)
    out[:, 0] = (q << 2) | ((1 - s) << 1) | s
    out[:, 1] = ((a & 0x7F) << 1) | 1
    out[:, 2] = a >> 7
    out[:, 3] = d & 0xFF
    out[:, 4] = d >> 8
    return out.tobytes()


def decode_node(data: bytes) -> Node | None:
    """Decode 5 bytes; None when the check bits say the stream is misaligned."""
    if len(data) != NODE_LEN:
        raise ValueError(f"a node is 5 bytes, got {len(data)}")
    b0, b1, b2, b3, b4 = data
    s = b0 & 1
    if s == (b0 >> 1) & 1 or not b1 & 1:
        return None
    angle_q6 = (b1 >> 1) | (b2 << 7)
    return Node(bool(s), b0 >> 2, angle_q6 / 64.0, (b3 | (b4 << 8)) / 4.0)


@dataclass
class NodeBatch:
    """Decoded nodes as arrays: start flag, quality, raw angle (deg), distance (mm)."""

    start: npt.NDArray[np.bool_]
    quality: npt.NDArray[np.uint8]
    angle_deg: npt.NDArray[np.float64]
    distance_mm: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.start)

    @staticmethod
    def empty() -> NodeBatch:
        """A batch with no nodes."""
        return NodeBatch(
            np.zeros(0, bool), np.zeros(0, np.uint8), np.zeros(0), np.zeros(0)
        )

    @staticmethod
    def concat(batches: list[NodeBatch]) -> NodeBatch:
        """Join batches in order."""
        if not batches:
            return NodeBatch.empty()
        if len(batches) == 1:
            return batches[0]
        return NodeBatch(
            np.concatenate([b.start for b in batches]),
            np.concatenate([b.quality for b in batches]),
            np.concatenate([b.angle_deg for b in batches]),
            np.concatenate([b.distance_mm for b in batches]),
        )

    def slice(self, lo: int, hi: int) -> NodeBatch:
        """Nodes ``lo`` to ``hi`` (exclusive)."""
        return NodeBatch(
            self.start[lo:hi], self.quality[lo:hi], self.angle_deg[lo:hi], self.distance_mm[lo:hi]
        )


def _decode_aligned(arr: npt.NDArray[np.uint8]) -> NodeBatch:
    b0 = arr[:, 0]
    b1 = arr[:, 1].astype(np.uint16)
    b2 = arr[:, 2].astype(np.uint16)
    angle_q6 = (b1 >> 1) | (b2 << 7)
    dist_q2 = arr[:, 3].astype(np.uint16) | (arr[:, 4].astype(np.uint16) << 8)
    return NodeBatch(
        (b0 & 1).astype(bool),
        (b0 >> 2).astype(np.uint8),
        angle_q6.astype(np.float64) / 64.0,
        dist_q2.astype(np.float64) / 4.0,
    )


@dataclass
class NodeStreamDecoder:
    """Decode a stream of 5-byte nodes, resynchronising after bad bytes.

    Aligned runs are checked and decoded with numpy in one go; at the first node whose check
    bits fail, one byte is dropped (``resync_bytes`` counts them) and decoding resumes. Nodes
    whose angle is above 360° (possible only when misaligned) are dropped too.
    """

    _buf: bytearray = field(default_factory=bytearray)
    resync_bytes: int = 0
    nodes: int = 0

    def reset(self) -> None:
        """Forget buffered bytes (after a STOP, a reconnect)."""
        self._buf.clear()

    def feed(self, data: bytes) -> NodeBatch:
        """Add ``data``; return every valid node it completes, in order."""
        self._buf += data
        buf = bytes(self._buf)  # numpy views must not pin the resizable buffer
        pos = 0
        parts: list[NodeBatch] = []
        while len(buf) - pos >= NODE_LEN:
            n = (len(buf) - pos) // NODE_LEN
            arr = np.frombuffer(buf, dtype=np.uint8, count=n * NODE_LEN, offset=pos).reshape(
                n, NODE_LEN
            )
            b0 = arr[:, 0]
            ok = (((b0 ^ (b0 >> 1)) & 1) == 1) & ((arr[:, 1] & 1) == 1)
            ok &= ((arr[:, 1].astype(np.uint16) >> 1) | (arr[:, 2].astype(np.uint16) << 7)) < (
                360 * 64
            )
            if bool(ok.all()):
                parts.append(_decode_aligned(arr))
                pos += n * NODE_LEN
                break
            bad = int(np.argmin(ok))
            if bad:
                parts.append(_decode_aligned(arr[:bad]))
            pos += bad * NODE_LEN + 1
            self.resync_bytes += 1
        del self._buf[:pos]
        batch = NodeBatch.concat(parts)
        self.nodes += len(batch)
        return batch


@dataclass
class ScanAssembler:
    """Cut the node stream into revolutions at each start flag.

    ``feed`` returns the revolutions completed by a batch (each as one :class:`NodeBatch`).
    The nodes before the first start flag ever seen are dropped (a partial revolution), and a
    revolution with fewer than ``min_nodes`` nodes is dropped and counted in ``short_scans``.
    A start flag counts only on a node within ``start_window_deg`` of the raw 0° (where the A1
    sets it) and after at least ``min_nodes`` nodes of the revolution in progress: a false node
    made of garbage bytes then rarely cuts a revolution in two.

    Where one still does, the two pieces are not scans: what a piece lacks would read as
    free space ("no return") to the stop zone and the costmap. A revolution whose nodes leave
    a gap wider than ``max_gap_deg`` anywhere round the circle (the A1 reports a node about
    every degree, with or without a return) is dropped and counted in ``partial_scans``.
    Garbage nodes inside a whole revolution only add near returns (a bin keeps its nearest),
    which the stop zone errs on the safe side with. Found by the 24-hour soak: in a
    lidar-garbage burst the rover started towards a person standing beside it.
    """

    min_nodes: int = 20
    start_window_deg: float = 30.0
    max_gap_deg: float = 15.0
    _parts: list[NodeBatch] = field(default_factory=list)
    _synced: bool = False
    short_scans: int = 0
    partial_scans: int = 0
    revolutions: int = 0
    completed: int = 0  # revolutions ended, kept or dropped
    last_length: int = 0  # nodes of the last one

    def reset(self) -> None:
        """Drop the revolution in progress."""
        self._parts.clear()
        self._synced = False

    def _largest_gap_deg(self, rev: NodeBatch) -> float:
        angles = np.sort(rev.angle_deg)
        wrap = 360.0 - float(angles[-1]) + float(angles[0])
        return max(wrap, float(np.max(np.diff(angles)))) if len(angles) > 1 else 360.0

    def _complete(self, rev: NodeBatch, out: list[NodeBatch]) -> None:
        """A revolution ended: keep it, or drop and count it (see the class docstring)."""
        self.completed += 1
        self.last_length = len(rev)
        if len(rev) < self.min_nodes:
            self.short_scans += 1
        elif self._largest_gap_deg(rev) > self.max_gap_deg:
            self.partial_scans += 1
        else:
            out.append(rev)
            self.revolutions += 1

    @property
    def in_progress(self) -> int:
        """Nodes of the revolution in progress (received since its start flag)."""
        return sum(len(part) for part in self._parts)

    def feed(self, batch: NodeBatch) -> list[NodeBatch]:
        """Add decoded nodes; return the revolutions they complete."""
        out: list[NodeBatch] = []
        if len(batch) == 0:
            return out
        w = self.start_window_deg
        near_zero = (batch.angle_deg < w) | (batch.angle_deg > 360.0 - w)
        starts = np.flatnonzero(batch.start & near_zero)
        lo = 0
        for idx in starts:
            i = int(idx)
            if self._synced:
                in_progress = sum(len(part) for part in self._parts) + (i - lo)
                if in_progress < self.min_nodes:
                    continue  # too early for a new revolution: a false start flag
                if i > lo:
                    self._parts.append(batch.slice(lo, i))
                self._complete(NodeBatch.concat(self._parts), out)
            self._parts = []
            self._synced = True
            lo = i
        if self._synced and lo < len(batch):
            self._parts.append(batch.slice(lo, len(batch)))
        return out


def raw_to_laser_rad(
    angle_deg: npt.NDArray[np.float64], offset_rad: float = 0.0
) -> npt.NDArray[np.float64]:
    """Raw clockwise degrees → laser-frame counter-clockwise radians in [-pi, pi).

    ``laser = pi - raw + offset`` (rplidar_ros, not inverted; hardware.md §5.5).
    """
    a = math.pi - np.radians(angle_deg) + offset_rad
    return np.asarray((a + math.pi) % (2 * math.pi) - math.pi, dtype=np.float64)


def laser_to_raw_deg(
    angle_rad: npt.NDArray[np.float64], offset_rad: float = 0.0
) -> npt.NDArray[np.float64]:
    """Inverse of :func:`raw_to_laser_rad`: raw clockwise degrees in [0, 360)."""
    return np.asarray(np.degrees(math.pi - angle_rad + offset_rad) % 360.0, dtype=np.float64)


def revolution_to_ranges(
    rev: NodeBatch,
    beams: int,
    range_min_m: float,
    range_max_m: float,
    offset_rad: float = 0.0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Bin one revolution into ``beams`` fixed angles (angle compensation).

    Bin ``i`` is centred on ``-pi + i * 2pi/beams`` in the laser frame. A bin keeps the nearest
    valid return; bins without a sample or with distance 0 hold ``inf`` (no return), samples
    outside ``[range_min_m, range_max_m]`` are dropped.

    Returns:
        ``(ranges_m, intensities)``, both of length ``beams``.
    """
    ranges = np.full(beams, np.inf)
    intens = np.zeros(beams)
    if len(rev) == 0:
        return ranges, intens
    inc = 2 * math.pi / beams
    laser = raw_to_laser_rad(rev.angle_deg, offset_rad)
    idx = np.floor((laser + math.pi) / inc + 0.5).astype(np.int64) % beams
    r = rev.distance_mm / 1000.0
    valid = (rev.distance_mm > 0) & (r >= range_min_m) & (r <= range_max_m)
    if not valid.any():
        return ranges, intens
    idx_v = idx[valid]
    r_v = r[valid]
    np.minimum.at(ranges, idx_v, r_v)
    # Intensity of the sample that won its bin.
    won = ranges[idx_v] == r_v
    intens[idx_v[won]] = rev.quality[valid][won]
    return ranges, intens
