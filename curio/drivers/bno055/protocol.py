"""BNO055 register map, scales and conversions (pure; no I/O). hardware.md §6.

* Register addresses (page 0 and the page-1 defaults), operating modes, UNIT_SEL bits.
* :func:`decode_block` turns the 26 data bytes Curio reads each cycle (GYR, EUL, QUA, LIA at
  0x14..0x2D) into SI values with the scale that matches the UNIT_SEL actually written (the
  degree and radian scales are not consistent: 16 LSB/dps but 900 LSB/rad/s);
  :func:`encode_block` is its inverse (the fake bus uses it).
* :func:`check_sample` is the defence against the Raspberry Pi's clock-stretching corruption
  (§6.6): quaternion norm, all-zero reads, physically impossible rates.
* :func:`chip_quat_to_rep103`: the fused quaternion comes as (w, x, y, z) at 2^14 LSB; with the
  axis remap (AXIS_MAP_CONFIG / AXIS_MAP_SIGN) set so the chip's axes are ``imu_link``'s (x
  forward, y left, z up) it is a right-handed rotation of ``imu_link`` in the fusion frame, and
  becomes a normalised REP-103 (x, y, z, w) quaternion. The Euler heading register is the
  compass sense (clockwise) and is not used.
* The 22-byte calibration profile (0x55..0x6A) and its JSON form.

Units: rad/s, m/s², °C; quaternions unitless.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum

__all__ = [
    "CALIB_PROFILE_LEN",
    "CHIP_ID_VALUE",
    "CalibrationProfile",
    "Mode",
    "Reg",
    "Sample",
    "check_sample",
    "chip_quat_to_rep103",
    "decode_block",
    "decode_calib_stat",
    "encode_block",
    "quat_multiply",
    "rep103_to_chip_quat",
    "sample_jump",
]

CHIP_ID_VALUE = 0xA0
ACC_ID_VALUE = 0xFB
MAG_ID_VALUE = 0x32
GYR_ID_VALUE = 0x0F
ADDRESSES = (0x28, 0x29)
CALIB_PROFILE_LEN = 22
QUAT_SCALE = 1 << 14
GRAVITY_MPS2 = 9.80665


class Reg(IntEnum):
    """Page-0 register addresses (and the page-1 ones the fake bus models)."""

    CHIP_ID = 0x00
    ACC_ID = 0x01
    MAG_ID = 0x02
    GYR_ID = 0x03
    SW_REV_LSB = 0x04
    SW_REV_MSB = 0x05
    BL_REV = 0x06
    PAGE_ID = 0x07
    ACC_DATA = 0x08
    MAG_DATA = 0x0E
    GYR_DATA = 0x14
    EUL_DATA = 0x1A
    QUA_DATA = 0x20
    LIA_DATA = 0x28
    GRV_DATA = 0x2E
    TEMP = 0x34
    CALIB_STAT = 0x35
    ST_RESULT = 0x36
    INT_STA = 0x37
    SYS_CLK_STATUS = 0x38
    SYS_STATUS = 0x39
    SYS_ERR = 0x3A
    UNIT_SEL = 0x3B
    OPR_MODE = 0x3D
    PWR_MODE = 0x3E
    SYS_TRIGGER = 0x3F
    TEMP_SOURCE = 0x40
    AXIS_MAP_CONFIG = 0x41
    AXIS_MAP_SIGN = 0x42
    ACC_OFFSET = 0x55
    MAG_RADIUS_MSB = 0x6A


class Mode(IntEnum):
    """OPR_MODE values (low nibble)."""

    CONFIG = 0x00
    ACCONLY = 0x01
    MAGONLY = 0x02
    GYROONLY = 0x03
    ACCMAG = 0x04
    ACCGYRO = 0x05
    MAGGYRO = 0x06
    AMG = 0x07
    IMU = 0x08
    COMPASS = 0x09
    M4G = 0x0A
    NDOF_FMC_OFF = 0x0B
    NDOF = 0x0C


FUSION_MODES = frozenset({Mode.IMU, Mode.COMPASS, Mode.M4G, Mode.NDOF_FMC_OFF, Mode.NDOF})
SYS_STATUS_FUSION = 5
SYS_STATUS_NO_FUSION = 6
SYS_TRIGGER_RST_SYS = 0x20
SYS_TRIGGER_EXT_CLK = 0x80

# UNIT_SEL bits.
UNIT_ACC_MG = 0x01
UNIT_GYR_RPS = 0x02
UNIT_EUL_RAD = 0x04
UNIT_TEMP_F = 0x10
UNIT_ANDROID = 0x80
#: What Curio writes: m/s², rad/s, rad, °C, Windows orientation.
CURIO_UNIT_SEL = UNIT_GYR_RPS | UNIT_EUL_RAD

# The data Curio reads each cycle, in ONE transaction (an all-zero or NACKed read then hits the
# whole sample, which the checks catch): 0x13..0x2D = a sacrificial byte (the Pi's
# clock-stretching bug sets bit 7 of the *first* byte of a read, hardware.md §6.6), GYR, EUL,
# QUA and LIA. CALIB_STAT is read once a second.
DATA_BLOCK = (Reg.GYR_DATA - 1, 27)
DATA_LEN = 26

SYS_ERR_TEXT = {
    0: "no error",
    1: "peripheral initialisation error",
    2: "system initialisation error",
    3: "self-test failed",
    4: "register map value out of range",
    5: "register map address out of range",
    6: "register map write error",
    7: "low-power mode not available for the selected operating mode",
    8: "accelerometer power mode not available",
    9: "fusion algorithm configuration error",
    10: "sensor configuration error",
}


def gyro_lsb_per_unit(unit_sel: int) -> float:
    """LSB per rad/s for the UNIT_SEL in force (900 in rad/s mode, 16·180/π in dps mode)."""
    return 900.0 if unit_sel & UNIT_GYR_RPS else 16.0 * 180.0 / math.pi


def accel_lsb_per_unit(unit_sel: int) -> float:
    """LSB per m/s² (100 in m/s² mode; 1 LSB = 1 mg otherwise)."""
    return 100.0 if not unit_sel & UNIT_ACC_MG else 1000.0 / GRAVITY_MPS2


def euler_lsb_per_unit(unit_sel: int) -> float:
    """LSB per radian for the Euler registers."""
    return 900.0 if unit_sel & UNIT_EUL_RAD else 16.0 * 180.0 / math.pi


@dataclass(frozen=True, slots=True)
class Sample:
    """One decoded reading, chip axes (= ``imu_link`` with the axis remap written).

    Attributes:
        quat_wxyz: fused orientation (w, x, y, z), not yet normalised.
        gyro_radps: angular velocity (x, y, z), rad/s.
        linear_accel_mps2: gravity-free acceleration (x, y, z), m/s².
        heading_rad: the Euler heading register (compass sense: clockwise), radians.
        calibration: (sys, gyr, acc, mag), each 0..3 (read separately from CALIB_STAT).
    """

    quat_wxyz: tuple[float, float, float, float]
    gyro_radps: tuple[float, float, float]
    linear_accel_mps2: tuple[float, float, float]
    heading_rad: float = 0.0
    calibration: tuple[int, int, int, int] = (0, 0, 0, 0)


def decode_calib_stat(value: int) -> tuple[int, int, int, int]:
    """CALIB_STAT → (sys, gyr, acc, mag)."""
    return ((value >> 6) & 3, (value >> 4) & 3, (value >> 2) & 3, value & 3)


def encode_calib_stat(levels: tuple[int, int, int, int]) -> int:
    """(sys, gyr, acc, mag) → CALIB_STAT."""
    s, g, a, m = (max(0, min(3, v)) for v in levels)
    return (s << 6) | (g << 4) | (a << 2) | m


def decode_block(
    data: bytes, unit_sel: int, calibration: tuple[int, int, int, int] = (0, 0, 0, 0)
) -> Sample:
    """Decode the 26 bytes 0x14..0x2D (GYR, EUL, QUA, LIA) with the scales of ``unit_sel``.

    Raises:
        ValueError: not 26 bytes.
    """
    if len(data) != DATA_LEN:
        raise ValueError(f"need {DATA_LEN} bytes (0x14..0x2D), got {len(data)}")
    v = struct.unpack("<13h", data)
    g = gyro_lsb_per_unit(unit_sel)
    e = euler_lsb_per_unit(unit_sel)
    a = accel_lsb_per_unit(unit_sel)
    return Sample(
        (v[6] / QUAT_SCALE, v[7] / QUAT_SCALE, v[8] / QUAT_SCALE, v[9] / QUAT_SCALE),
        (v[0] / g, v[1] / g, v[2] / g),
        (v[10] / a, v[11] / a, v[12] / a),
        v[3] / e,
        calibration,
    )


def _i16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


def encode_block(sample: Sample, unit_sel: int) -> bytes:
    """Inverse of :func:`decode_block`: the 26 bytes 0x14..0x2D (roll and pitch 0)."""
    g = gyro_lsb_per_unit(unit_sel)
    e = euler_lsb_per_unit(unit_sel)
    a = accel_lsb_per_unit(unit_sel)
    return struct.pack(
        "<13h",
        *(_i16(x * g) for x in sample.gyro_radps),
        _i16(sample.heading_rad * e), 0, 0,
        *(_i16(x * QUAT_SCALE) for x in sample.quat_wxyz),
        *(_i16(x * a) for x in sample.linear_accel_mps2),
    )


def check_sample(sample: Sample, fusion_running: bool) -> str | None:
    """Return why ``sample`` looks corrupted (clock-stretching garbage), or None if plausible."""
    w, x, y, z = sample.quat_wxyz
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if fusion_running and abs(norm - 1.0) > 0.01:
        if norm == 0.0:
            return "all-zero quaternion"
        return f"quaternion norm {norm:.4f} (should be 1)"
    if max(abs(v) for v in sample.gyro_radps) > 2000.0 * math.pi / 180.0 * 1.01:
        return "angular rate beyond the gyro's 2000 dps range"
    if max(abs(v) for v in sample.linear_accel_mps2) > 16.0 * GRAVITY_MPS2:
        return "acceleration beyond 16 g"
    return None


def sample_jump(a: Sample, b: Sample) -> str | None:
    """Why ``b`` cannot follow ``a`` 10 ms later (an LSB flip in an MSB), or None."""
    if max(abs(x - y) for x, y in zip(a.quat_wxyz, b.quat_wxyz, strict=True)) > 0.012:
        return "orientation jump"
    if max(abs(x - y) for x, y in zip(a.gyro_radps, b.gyro_radps, strict=True)) > 0.25:
        return "angular-rate jump"
    if max(abs(x - y) for x, y in
           zip(a.linear_accel_mps2, b.linear_accel_mps2, strict=True)) > 2.0:
        return "acceleration jump"
    return None


def quat_multiply(
    a: tuple[float, float, float, float], b: tuple[float, float, float, float]
) -> tuple[float, float, float, float]:
    """Hamilton product of two (x, y, z, w) quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def chip_quat_to_rep103(
    quat_wxyz: tuple[float, float, float, float],
) -> tuple[float, float, float, float] | None:
    """Chip (w, x, y, z) → normalised REP-103 (x, y, z, w); None for a zero quaternion."""
    w, x, y, z = quat_wxyz
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if norm < 1e-6:
        return None
    if w < 0:  # one canonical sign
        w, x, y, z = -w, -x, -y, -z
    return (x / norm, y / norm, z / norm, w / norm)


def rep103_to_chip_quat(
    quat_xyzw: tuple[float, float, float, float],
) -> tuple[float, float, float, float]:
    """REP-103 (x, y, z, w) → chip order (w, x, y, z)."""
    x, y, z, w = quat_xyzw
    return (w, x, y, z)


@dataclass(frozen=True, slots=True)
class CalibrationProfile:
    """The 22-byte calibration profile at 0x55..0x6A (offsets and radii, i16 LE each)."""

    data: bytes

    def __post_init__(self) -> None:
        if len(self.data) != CALIB_PROFILE_LEN:
            raise ValueError(f"a BNO055 calibration profile is 22 bytes, got {len(self.data)}")

    @property
    def values(self) -> tuple[int, ...]:
        """acc x/y/z, mag x/y/z, gyr x/y/z offsets, acc radius, mag radius."""
        return struct.unpack("<11h", self.data)

    def problem(self) -> str | None:
        """Why this profile must not be written (a zero MAG_RADIUS can fault the chip)."""
        v = self.values
        if v[10] == 0:
            return "MAG_RADIUS is 0 (restoring it can put the BNO055 in an error state)"
        if not -1000 <= v[9] <= 1000 or not -960 <= v[10] <= 960:
            return f"radii out of range (acc {v[9]}, mag {v[10]})"
        return None

    def to_json(self) -> dict[str, object]:
        """A JSON-able form (hex bytes plus decoded values, for people reading the file)."""
        names = ("acc_offset_x", "acc_offset_y", "acc_offset_z", "mag_offset_x",
                 "mag_offset_y", "mag_offset_z", "gyr_offset_x", "gyr_offset_y",
                 "gyr_offset_z", "acc_radius", "mag_radius")
        return {"profile_hex": self.data.hex(), "values": dict(zip(names, self.values,
                                                                  strict=True))}

    @classmethod
    def from_json(cls, obj: object) -> CalibrationProfile:
        """Parse :meth:`to_json` output.

        Raises:
            ValueError: not the expected shape.
        """
        if not isinstance(obj, dict) or not isinstance(obj.get("profile_hex"), str):
            raise ValueError("expected an object with a 'profile_hex' string")
        return cls(bytes.fromhex(obj["profile_hex"]))
