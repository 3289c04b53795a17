"""The BNO055 emulator: a fake I2C bus with the chip on it, fed by the simulator (§7.4 of
hardware.md).

:class:`Bno055Emulator` exposes the part of ``smbus2.SMBus`` the driver uses —
``read_byte_data``, ``write_byte_data``, ``read_i2c_block_data`` (≤ 32 bytes),
``write_i2c_block_data``, ``close`` — so the real :class:`~curio.drivers.bno055.driver.Bno055Driver`
runs against it unchanged. Behind it is the chip as the datasheet describes it:

* answers at its address only (0x28, or 0x29 with ADR high); elsewhere ``OSError(EREMOTEIO)``;
* a two-page register file switched by PAGE_ID, auto-increment on block reads and writes;
* IDs 0xA0/0xFB/0x32/0x0F, SW_REV 0x0311, BL_REV 0x15, ST_RESULT 0x0F;
* power-on (``power_on_s``) and RST_SYS (0.65 s) windows during which every access is NACKed,
  then POR defaults: CONFIG mode, UNIT_SEL 0x80, AXIS_MAP 0x24/0x00, data registers zero;
* configuration registers writable in CONFIG mode only (else SYS_ERR = 6); OPR_MODE,
  PAGE_ID, SYS_TRIGGER and PWR_MODE always;
* in a fusion mode SYS_STATUS = 5 and the data registers follow ``source(now)`` (the world's
  ``imu_sample``, a REP-103 ``Imu``) at 100 Hz, scaled per the UNIT_SEL in force; IMU mode's
  heading is relative to the heading at the mode switch, NDOF's is absolute;
* CALIB_STAT grows with time in a fusion mode (gyro after ~1.5 s, accel ~4 s, mag ~6 s in
  NDOF); a written calibration profile makes it reach 3 at once. The 22-byte profile reads back
  only in CONFIG mode.

Fault knobs (:class:`Bno055Faults`): ``missing`` (nothing on the bus), ``chip_id`` (another
chip answers), ``io_error_rate`` (NACK/EREMOTEIO), and the Pi clock-stretching corruptions
``bit7_rate`` (bit 7 set in the first byte), ``zero_rate`` (all-zero read) and
``lsb_flip_rate`` (bit 0 of an MSB flipped). All randomness from ``seed``.
"""

from __future__ import annotations

import errno
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import quat_to_yaw, yaw_to_quat
from curio.core.messages import Imu
from curio.core.parts import Part
from curio.drivers.bno055 import protocol as r

__all__ = ["Bno055Emulator", "Bno055Faults", "ImuWorld"]

RESET_S = 0.65
# Page-0 configuration registers (writable in CONFIG mode only).
_CONFIG_REGS = frozenset(
    {r.Reg.UNIT_SEL, r.Reg.TEMP_SOURCE, r.Reg.AXIS_MAP_CONFIG, r.Reg.AXIS_MAP_SIGN}
    | set(range(0x43, 0x6B))
)
_ALWAYS_WRITABLE = frozenset({r.Reg.OPR_MODE, r.Reg.PAGE_ID, r.Reg.SYS_TRIGGER, r.Reg.PWR_MODE})
_READ_ONLY = frozenset(range(0x00, 0x07)) | frozenset(range(0x08, 0x3B))


class ImuWorld(Protocol):
    """What the emulator needs from the simulator's world."""

    def imu_sample(self, stamp: float) -> Imu:
        """The reading at clock time ``stamp`` in ``imu_link``."""
        ...


@dataclass
class Bno055Faults:
    """Fault knobs of the fake bus (rates are per transaction, 0..1).

    ``frozen``: the chip's output registers stop changing (it still answers on the bus), as
    a BNO055 does after some I2C upsets, until it is re-initialised (a switch to CONFIG mode
    or a reset clears it).
    """

    missing: bool = False
    frozen: bool = False
    chip_id: int = r.CHIP_ID_VALUE
    io_error_rate: float = 0.0
    bit7_rate: float = 0.0
    zero_rate: float = 0.0
    lsb_flip_rate: float = 0.0


def _eremoteio() -> OSError:
    return OSError(errno.EREMOTEIO, "Remote I/O error")


class Bno055Emulator:
    """An I2C bus (``smbus2.SMBus`` subset) with one simulated BNO055.

    Args:
        source: the reading at a time (``world.imu_sample``); None gives a still chip.
        now: the clock (``clock.now``), seconds.
        address: where the chip answers (0x28 or 0x29).
        power_on_s: how long after construction the chip stays silent (POR).
        seed: fault randomness and the chip's "true" calibration offsets.
    """

    def __init__(
        self,
        source: Callable[[float], Imu] | None,
        now: Callable[[], float],
        *,
        address: int = 0x28,
        power_on_s: float = 0.4,
        seed: int = 0,
    ) -> None:
        self.source = source
        self.now = now
        self.address = address
        self.faults = Bno055Faults()
        self._rng = np.random.default_rng(seed)
        offsets = [*self._rng.integers(-40, 40, 9).tolist(), 1000, 700]
        self.true_profile = np.array(offsets, dtype="<i2").tobytes()
        self.transactions = 0
        self.closed = False
        self._power_on(self.now() + power_on_s)

    @classmethod
    def for_world(cls, world: ImuWorld, clock: Clock, cfg: Config, seed: int,
                  link: Path | None = None) -> Bno055Emulator:
        """The chip in the simulator's ``world`` (emulated mode).

        Args:
            world: the simulator's world (``imu_sample``).
            clock: the application clock.
            cfg: the configuration (``drivers.imu.address``).
            seed: fault randomness and the chip's calibration offsets.
            link: unused: the bus is in memory, there is no device node.
        """
        return cls(world.imu_sample, clock.now, address=cfg.drivers.imu.address, seed=seed)

    @property
    def path(self) -> None:
        """No device node: the bus is in memory."""
        return None

    def open(self) -> None:
        """Nothing to open: the bus is in memory."""

    def parts(self) -> list[Part]:
        """Nothing runs the emulator: the driver calls it."""
        return []

    # --- chip state ---------------------------------------------------------------------------
    def _power_on(self, ready_at: float) -> None:
        self.faults.frozen = False
        self._ready_at = ready_at
        self._page = 0
        p0 = bytearray(128)
        p0[r.Reg.CHIP_ID] = r.CHIP_ID_VALUE
        p0[r.Reg.ACC_ID] = r.ACC_ID_VALUE
        p0[r.Reg.MAG_ID] = r.MAG_ID_VALUE
        p0[r.Reg.GYR_ID] = r.GYR_ID_VALUE
        p0[r.Reg.SW_REV_LSB] = 0x11
        p0[r.Reg.SW_REV_MSB] = 0x03
        p0[r.Reg.BL_REV] = 0x15
        p0[r.Reg.ST_RESULT] = 0x0F
        p0[r.Reg.UNIT_SEL] = 0x80
        p0[r.Reg.AXIS_MAP_CONFIG] = 0x24
        p0[r.Reg.AXIS_MAP_SIGN] = 0x00
        p0[0x6A] = 0  # profile zero until calibrated
        p1 = bytearray(128)
        p1[0x08], p1[0x09], p1[0x0A], p1[0x0B] = 0x0D, 0x6D, 0x38, 0x00
        self._pages = [p0, p1]
        self._mode = r.Mode.CONFIG
        self._mode_since = self.now()
        self._fusion_time_s = 0.0  # time spent in fusion modes since power-on (calibration)
        self._profile_loaded = False
        self._yaw0 = 0.0
        self._last_sample_t = -math.inf
        self.resets = getattr(self, "resets", -1) + 1

    @property
    def mode(self) -> int:
        """The current operating mode."""
        return int(self._mode)

    def _check_addr(self, addr: int) -> None:
        self.transactions += 1
        if self.closed:
            raise OSError(errno.EBADF, "bus closed")
        if self.faults.missing or addr != self.address:
            raise _eremoteio()
        if self.now() < self._ready_at:
            raise _eremoteio()  # booting: no ACK
        if self.faults.io_error_rate and self._rng.random() < self.faults.io_error_rate:
            raise _eremoteio()

    def _calib_levels(self) -> tuple[int, int, int, int]:
        if self._mode not in r.FUSION_MODES:
            return (0, 0, 0, 0)
        t = self._fusion_time_s + (self.now() - self._mode_since)
        if self._profile_loaded:
            t += 10.0
        gyr = min(3, int(t / 0.5))  # 3 after 1.5 s still
        acc = min(3, int(t / 1.4))
        mag = min(3, int(t / 2.0)) if self._mode == r.Mode.NDOF else 0
        sys = min(gyr, acc, mag) if self._mode == r.Mode.NDOF else min(gyr, acc)
        return (sys, gyr, acc, mag)

    def _refresh_data(self) -> None:
        now = self.now()
        if self._mode not in r.FUSION_MODES or now - self._last_sample_t < 0.01 \
                or self.faults.frozen:
            return
        self._last_sample_t = now
        imu = self.source(now) if self.source is not None else Imu(now)
        yaw = quat_to_yaw(imu.orientation_xyzw)
        q = imu.orientation_xyzw
        if self._mode == r.Mode.IMU:  # relative heading: 0 at the mode switch
            q = r.quat_multiply(yaw_to_quat(-self._yaw0), q)
        unit_sel = self._pages[0][r.Reg.UNIT_SEL]
        la = imu.linear_acceleration_mps2
        grav = (0.0, 0.0, r.GRAVITY_MPS2)
        heading = (-quat_to_yaw(q)) % (2 * math.pi)  # compass sense
        sample = r.Sample(r.rep103_to_chip_quat(q), imu.angular_velocity_radps, la, heading)
        p0 = self._pages[0]
        p0[r.Reg.GYR_DATA : r.Reg.GYR_DATA + r.DATA_LEN] = r.encode_block(sample, unit_sel)
        a = r.accel_lsb_per_unit(unit_sel)
        acc = [round((la[i] + grav[i]) * a) for i in range(3)]
        p0[r.Reg.ACC_DATA : r.Reg.ACC_DATA + 6] = np.array(acc, "<i2").tobytes()
        p0[r.Reg.MAG_DATA : r.Reg.MAG_DATA + 6] = np.array(
            [round(20 * 16 * math.cos(yaw)), round(-20 * 16 * math.sin(yaw)), -40 * 16], "<i2"
        ).tobytes()
        p0[r.Reg.GRV_DATA : r.Reg.GRV_DATA + 6] = np.array(
            [round(x * a) for x in grav], "<i2"
        ).tobytes()
        p0[r.Reg.TEMP] = 26

    def _set_mode(self, value: int) -> None:
        now = self.now()
        new = value & 0x0F
        if self._mode in r.FUSION_MODES:
            self._fusion_time_s += now - self._mode_since
        try:
            self._mode = r.Mode(new)
        except ValueError:
            self._pages[0][r.Reg.SYS_ERR] = 4
            return
        self._mode_since = now
        p0 = self._pages[0]
        p0[r.Reg.OPR_MODE] = new
        if self._mode == r.Mode.CONFIG:
            self.faults.frozen = False  # re-initialising the chip clears a frozen output
            p0[r.Reg.SYS_STATUS] = 0
            p0[0x08:0x34] = bytes(0x34 - 0x08)  # data registers read 0 in CONFIG
            self._ready_at = max(self._ready_at, now + 0.019)
        else:
            p0[r.Reg.SYS_STATUS] = (
                r.SYS_STATUS_FUSION if self._mode in r.FUSION_MODES else r.SYS_STATUS_NO_FUSION
            )
            if self.source is not None:
                self._yaw0 = quat_to_yaw(self.source(now).orientation_xyzw)
            self._last_sample_t = -math.inf
            self._ready_at = max(self._ready_at, now + 0.007)

    def _read_reg(self, reg: int) -> int:
        p = self._pages[self._page]
        if self._page == 0:
            if reg == r.Reg.CALIB_STAT:
                return r.encode_calib_stat(self._calib_levels())
            if r.Reg.ACC_OFFSET <= reg <= r.Reg.MAG_RADIUS_MSB:
                if self._mode != r.Mode.CONFIG:
                    return 0
                if self._calib_levels_at_config() and not self._profile_loaded:
                    return self.true_profile[reg - r.Reg.ACC_OFFSET]
        return p[reg & 0x7F] if reg < 0x80 else 0

    def _calib_levels_at_config(self) -> bool:
        return self._fusion_time_s >= 4.2  # gyro and accel at level 3 by then

    def _write_reg(self, reg: int, value: int) -> None:
        value &= 0xFF
        p0 = self._pages[0]
        if reg == r.Reg.PAGE_ID:
            self._page = value & 1
            p0[r.Reg.PAGE_ID] = self._page
            self._pages[1][r.Reg.PAGE_ID] = self._page
            return
        if self._page == 1:
            if self._mode == r.Mode.CONFIG:
                self._pages[1][reg] = value
            return
        if reg == r.Reg.SYS_TRIGGER:
            if value & r.SYS_TRIGGER_RST_SYS:
                self._power_on(self.now() + RESET_S)
                return
            p0[reg] = value & 0xC1
            return
        if reg == r.Reg.OPR_MODE:
            self._set_mode(value)
            return
        if reg == r.Reg.PWR_MODE:
            p0[reg] = value & 0x03
            return
        if reg in _READ_ONLY:
            return
        if reg in _CONFIG_REGS and self._mode != r.Mode.CONFIG:
            p0[r.Reg.SYS_ERR] = 6
            return
        p0[reg] = value
        if reg == r.Reg.MAG_RADIUS_MSB:  # the last MSB of the profile latches it
            self._profile_loaded = True

    # --- corruption (the Pi's clock-stretching bug) -------------------------------------------
    def _corrupt(self, data: list[int]) -> list[int]:
        f = self.faults
        if f.zero_rate and self._rng.random() < f.zero_rate:
            return [0] * len(data)
        if f.bit7_rate and self._rng.random() < f.bit7_rate:
            data[0] |= 0x80
        if f.lsb_flip_rate and len(data) >= 2 and self._rng.random() < f.lsb_flip_rate:
            i = int(self._rng.integers(0, len(data) // 2)) * 2 + 1
            data[i] ^= 0x01
        return data

    # --- the smbus2 surface -------------------------------------------------------------------
    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """Read one register."""
        self._check_addr(i2c_addr)
        if register == r.Reg.CHIP_ID and self._page == 0:
            value = self.faults.chip_id
        else:
            self._refresh_data()
            value = self._read_reg(register)
        return self._corrupt([value])[0]

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        """Write one register."""
        self._check_addr(i2c_addr)
        self._write_reg(register, value)

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        """Read ``length`` (≤ 32) registers from ``register`` on (auto-increment)."""
        if not 0 < length <= 32:
            raise ValueError(f"SMBus block reads are 1..32 bytes, got {length}")
        self._check_addr(i2c_addr)
        self._refresh_data()
        data = [self._read_reg(register + i) for i in range(length)]
        if register == r.Reg.CHIP_ID and self._page == 0:
            data[0] = self.faults.chip_id
        return self._corrupt(data)

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        """Write ``data`` (≤ 32 bytes) from ``register`` on (auto-increment)."""
        if len(data) > 32:
            raise ValueError(f"SMBus block writes are at most 32 bytes, got {len(data)}")
        self._check_addr(i2c_addr)
        for i, value in enumerate(data):
            self._write_reg(register + i, value)

    def close(self) -> None:
        """Close the bus (further accesses fail with EBADF)."""
        self.closed = True

    def reopen(self) -> Bno055Emulator:
        """What ``SMBus(n)`` returns again after a close: the same chip, a fresh handle."""
        self.closed = False
        return self
