"""The BNO055 driver: smbus2 (or the fake bus), blocking calls off the event loop, ``/imu``.

Per session (:meth:`Bno055Driver.run` repeats sessions for ever):

1. open the I2C bus (``/dev/i2c-N``; a missing device node or a permission error says how to
   enable I2C or which group to join);
2. poll CHIP_ID until it reads 0xA0 (the chip does not ACK for ~650 ms after a reset). Nothing
   answering, or another id, produces a message naming the address (0x28 with ADR low, 0x29
   with ADR high), the wiring and ``i2cdetect``;
3. CONFIG mode, normal power, the clock source, UNIT_SEL (m/s², rad/s, rad, °C — always
   written and read back, since the reset value is documented inconsistently), the axis remap,
   the saved calibration profile (if any), then the operating mode (IMU or NDOF) and a check
   of SYS_STATUS / SYS_ERR;
4. every ``1 / rate_hz``: read 0x13..0x2D (a sacrificial byte, GYR, EUL, QUA, LIA) in one
   transaction, sanity-check it (:func:`~curio.drivers.bno055.protocol.check_sample`; a bad
   reading is re-read once, then dropped and counted), and publish an ``Imu`` in ``imu_link``
   with the REP-103 quaternion. CHIP_ID, OPR_MODE and CALIB_STAT are read every second: a chip
   that reset itself is re-initialised.

Calibration: once every sensor the mode uses reports level 3, the 22-byte profile is read (in
CONFIG mode) and saved atomically to ``calibration_path``; it is restored at the next start so
the rover needs no recalibration.

Errors: ``OSError`` on the bus and corrupted readings are counted. Corruption or I/O errors
above ``error_rate_warn`` make ``/health`` ``degraded`` with the fix for the Raspberry Pi's
clock-stretching bug (``dtparam=i2c_arm_baudrate=10000`` or the ``i2c-gpio`` overlay);
``max_consecutive_errors`` failures in a row end the session (``error``), and it restarts; so
does an output that froze (the same reading for ``frozen_timeout_s``: the chip answers, its
registers no longer change).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, TypeVar

from curio.core.bus import Bus
from curio.core.clock import Clock, wall_sleep
from curio.core.config import ImuConfig
from curio.core.fileio import atomic_write_json
from curio.core.messages import Imu
from curio.core.topics import IMU
from curio.drivers.bno055 import protocol as r
from curio.drivers.health import HealthReporter, ReportsHealth
from curio.drivers.session import Backoff, DeviceFault, SessionLoop

__all__ = ["Bno055Driver", "ImuFault", "SMBusLike", "open_smbus"]

log = logging.getLogger("curio.drivers.bno055")

T = TypeVar("T")

BAUD_FIX = (
    "the Raspberry Pi's I2C controller mishandles the BNO055's clock stretching: add "
    "'dtparam=i2c_arm_baudrate=10000' to /boot/firmware/config.txt and reboot, or use the "
    "software bus 'dtoverlay=i2c-gpio,bus=3,i2c_gpio_sda=23,i2c_gpio_scl=24' with "
    "drivers.imu.i2c_bus=3 (deploy/README.md)"
)


class SMBusLike(Protocol):
    """The part of ``smbus2.SMBus`` the driver uses (the fake bus implements it too)."""

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """Read one register."""
        ...

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        """Write one register."""
        ...

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        """Read up to 32 registers."""
        ...

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        """Write up to 32 registers."""
        ...

    def close(self) -> None:
        """Release the bus."""
        ...


def open_smbus(bus_number: int) -> SMBusLike:
    """Open ``/dev/i2c-<bus_number>`` with smbus2."""
    import smbus2

    bus: SMBusLike = smbus2.SMBus(bus_number)
    return bus


class ImuFault(DeviceFault):
    """A session-ending problem, phrased for the person who has to fix it."""


class Bno055Driver(ReportsHealth):
    """Reads a BNO055 and publishes ``/imu``, ``/health`` and events.

    Args:
        cfg: ``drivers.imu``.
        clock: the application clock.
        bus: the application bus.
        calibration_path: where the calibration profile is kept (``cfg.data_path(...)``).
        open_bus: returns an SMBus-like object (default: smbus2 on ``cfg.i2c_bus``).
        offload: run bus calls in a worker thread (True for real hardware; the in-memory fake
            bus may run inline, which keeps emulated runs deterministic).
    """

    name = "imu"

    def __init__(
        self,
        cfg: ImuConfig,
        clock: Clock,
        bus: Bus,
        *,
        calibration_path: Path,
        open_bus: Callable[[], SMBusLike] | None = None,
        offload: bool = True,
    ) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = bus
        self.calibration_path = calibration_path
        self.open_bus = open_bus or (lambda: open_smbus(cfg.i2c_bus))
        self.offload = offload
        self.addr = cfg.address
        self.calibration: tuple[int, int, int, int] = (0, 0, 0, 0)
        self.counters: dict[str, float] = {
            "samples": 0,
            "sessions": 0,
            "i2c_errors": 0,
            "suspect_readings": 0,
            "dropped_samples": 0,
            "reinits": 0,
            "calibration_saves": 0,
            "calibration_restored": 0,
            "frozen": 0,
        }
        self.reporter = HealthReporter(self.name, clock, bus, log, self.counters,
                                       extra=self._calibration_counters, publish_unchanged=True)
        self._smbus: SMBusLike | None = None
        self._unit_sel = r.CURIO_UNIT_SEL
        self._saved_this_session = False
        self._prev: r.Sample | None = None
        self._last_sample: tuple[Any, ...] | None = None
        self._same_since: float | None = None
        self._recent: deque[tuple[float, bool]] = deque()
        self._mode = r.Mode.NDOF if cfg.mode == "ndof" else r.Mode.IMU

    # --- I/O helpers --------------------------------------------------------------------------
    async def _io(self, fn: Callable[..., T], *args: Any) -> T:
        if self.offload:
            return await asyncio.to_thread(fn, *args)
        return fn(*args)

    def _dev(self) -> SMBusLike:
        if self._smbus is None:
            raise ImuFault("the I2C bus is not open")
        return self._smbus

    async def _read(self, reg: int, attempts: int = 1) -> int:
        for i in range(attempts):
            try:
                return await self._io(self._dev().read_byte_data, self.addr, reg)
            except OSError:
                self.counters["i2c_errors"] += 1
                if i == attempts - 1:
                    raise
        raise AssertionError("unreachable")

    async def _write(self, reg: int, value: int, attempts: int = 3) -> None:
        for i in range(attempts):
            try:
                await self._io(self._dev().write_byte_data, self.addr, reg, value)
                return
            except OSError:
                self.counters["i2c_errors"] += 1
                if i == attempts - 1:
                    raise

    async def _read_expect(self, reg: int, want: int, mask: int = 0xFF) -> int:
        """Read a register up to 3 times until it shows ``want`` (reads can be garbage)."""
        got = -1
        for _ in range(3):
            got = await self._read(reg, attempts=3)
            if got & mask == want:
                break
        return got

    def _where(self) -> str:
        return f"I2C bus {self.cfg.i2c_bus} address 0x{self.addr:02X}"

    def _running(self) -> str:
        return f"BNO055 running in {self._mode.name} mode at {self._where()}"

    # --- life cycle ---------------------------------------------------------------------------
    async def run(self) -> None:
        """Run sessions for ever; each failure is reported and retried."""
        reconnect_s = self.cfg.reconnect_s
        await SessionLoop(self.clock, self._session, self._report_down,
                          Backoff(reconnect_s, reconnect_s), after=self._close_bus,
                          on_abort=self._close_bus).run()

    async def close(self) -> None:
        """Release the bus."""
        await self._close_bus()

    async def _close_bus(self) -> None:
        dev, self._smbus = self._smbus, None
        if dev is not None:
            with contextlib.suppress(Exception):
                await self._io(dev.close)

    async def _session(self) -> None:
        self.counters["sessions"] += 1
        self._saved_this_session = False
        self._prev = None
        try:
            self._smbus = await self._io(self.open_bus)
        except FileNotFoundError as exc:
            raise ImuFault(
                f"/dev/i2c-{self.cfg.i2c_bus} does not exist: enable I2C "
                "(sudo raspi-config nonint do_i2c 0, or dtparam=i2c_arm=on in "
                "/boot/firmware/config.txt) and reboot"
            ) from exc
        except PermissionError as exc:
            raise ImuFault(
                f"no permission for /dev/i2c-{self.cfg.i2c_bus}: add the user to the 'i2c' "
                "group (sudo usermod -aG i2c $USER) and log in again"
            ) from exc
        except OSError as exc:
            raise ImuFault(f"cannot open I2C bus {self.cfg.i2c_bus}: {exc}") from exc
        try:
            await self._init_chip()
        except OSError as exc:  # a write failed 3 times: end the session, do not crash the part
            raise ImuFault(
                f"the BNO055 at {self._where()} stopped answering while being configured "
                f"({exc}): retrying; if this repeats, check the wiring and {BAUD_FIX}"
            ) from exc
        self.reporter.set_state("ok", self._running())
        await self._stream()

    async def _init_chip(self) -> None:
        await self._wait_chip_id(self.cfg.boot_timeout_s)
        await self._write(r.Reg.PAGE_ID, 0)
        await self._write(r.Reg.OPR_MODE, r.Mode.CONFIG)
        await self.clock.sleep(0.025)
        await self._write(r.Reg.PWR_MODE, 0x00)
        await self.clock.sleep(0.01)
        await self._write(r.Reg.SYS_TRIGGER, r.SYS_TRIGGER_EXT_CLK if self.cfg.external_crystal
                          else 0x00)
        await self.clock.sleep(0.01)
        await self._write(r.Reg.UNIT_SEL, self._unit_sel)
        got = await self._read_expect(r.Reg.UNIT_SEL, self._unit_sel, 0x97)
        if got & 0x97 != self._unit_sel:
            raise ImuFault(
                f"UNIT_SEL reads back 0x{got:02X} instead of 0x{self._unit_sel:02X} at "
                f"{self._where()}: the bus corrupts data — {BAUD_FIX}"
            )
        await self._write(r.Reg.AXIS_MAP_CONFIG, self.cfg.axis_map_config)
        await self._write(r.Reg.AXIS_MAP_SIGN, self.cfg.axis_map_sign)
        await self._restore_calibration()
        await self._write(r.Reg.OPR_MODE, self._mode)
        await self.clock.sleep(0.02)
        status = err = -1
        deadline = self.clock.now() + 1.0
        while self.clock.now() < deadline:
            try:
                status = await self._read(r.Reg.SYS_STATUS)
                err = await self._read(r.Reg.SYS_ERR)
            except OSError:
                status = err = -1
            if status == r.SYS_STATUS_FUSION:
                return
            await self.clock.sleep(0.05)
        raise ImuFault(
            f"the BNO055 at {self._where()} does not start its fusion (SYS_STATUS {status}, "
            f"SYS_ERR {err}: {r.SYS_ERR_TEXT.get(err, 'unknown')}); power-cycle it"
        )

    async def _wait_chip_id(self, timeout_s: float) -> None:
        deadline = self.clock.now() + timeout_s
        last_exc: OSError | None = None
        last_id: int | None = None
        while True:
            try:
                last_id = await self._read(r.Reg.CHIP_ID)
                if last_id == r.CHIP_ID_VALUE:
                    return
            except OSError as exc:
                last_exc = exc
            if self.clock.now() >= deadline:
                break
            await self.clock.sleep(0.05)
        other = 0x29 if self.addr == 0x28 else 0x28
        if last_id is not None:
            raise ImuFault(
                f"the chip at {self._where()} reports id 0x{last_id:02X}, not the BNO055's "
                f"0xA0: another device sits at this address, or the bus corrupts data — "
                f"{BAUD_FIX}"
            )
        raise ImuFault(
            f"no BNO055 answers at {self._where()} ({last_exc}): check the wiring (SDA to "
            f"GPIO2, SCL to GPIO3, VIN 3.3 V, GND), the address (0x28 with ADR low, 0x{other:02X} "
            f"otherwise: set drivers.imu.address), and run `i2cdetect -y {self.cfg.i2c_bus}`"
        )

    # --- calibration --------------------------------------------------------------------------
    async def _restore_calibration(self) -> None:
        path = self.calibration_path
        if not path.is_file():
            return
        try:
            profile = r.CalibrationProfile.from_json(json.loads(path.read_text("utf-8")))
        except (ValueError, OSError) as exc:
            log.warning("ignoring the calibration file %s: %s", path, exc)
            self.reporter.event("driver.imu_calibration_ignored", path=str(path), reason=str(exc))
            return
        problem = profile.problem()
        if problem is not None:
            log.warning("not restoring the calibration in %s: %s", path, problem)
            return
        data = list(profile.data)
        await self._io(self._dev().write_i2c_block_data, self.addr, r.Reg.ACC_OFFSET, data)
        self.counters["calibration_restored"] += 1
        log.info("restored the BNO055 calibration from %s", path)

    def _fully_calibrated(self, levels: tuple[int, int, int, int]) -> bool:
        _sys, gyr, acc, mag = levels
        if self._mode == r.Mode.NDOF:
            return gyr == acc == mag == 3
        return gyr == acc == 3

    async def _save_calibration(self) -> None:
        """Read the profile in CONFIG mode (fusion pauses ~40 ms) and save it atomically."""
        await self._write(r.Reg.OPR_MODE, r.Mode.CONFIG)
        await self.clock.sleep(0.025)
        try:
            raw = await self._io(
                self._dev().read_i2c_block_data, self.addr, r.Reg.ACC_OFFSET, r.CALIB_PROFILE_LEN
            )
        finally:
            await self._write(r.Reg.OPR_MODE, self._mode)
            await self.clock.sleep(0.02)
            self._prev = None  # IMU mode restarts its relative heading at the switch
        profile = r.CalibrationProfile(bytes(raw))
        problem = profile.problem()
        if problem is not None:
            log.warning("not saving the BNO055 calibration: %s", problem)
            return
        obj = profile.to_json()
        obj["levels"] = list(self.calibration)
        obj["mode"] = self._mode.name
        await self._io(atomic_write_json, self.calibration_path, obj)
        self.counters["calibration_saves"] += 1
        self.reporter.event("driver.imu_calibration_saved", path=str(self.calibration_path))

    # --- streaming ----------------------------------------------------------------------------
    def _read_once(self) -> r.Sample | None:
        """One block read (blocking); None after an I/O error."""
        start, length = r.DATA_BLOCK
        try:
            block = self._dev().read_i2c_block_data(self.addr, start, length)
        except OSError:
            self.counters["i2c_errors"] += 1
            self._note(False)
            return None
        # The first byte is sacrificial (it takes the clock-stretching bit-7 garbage).
        return r.decode_block(bytes(block[1:]), self._unit_sel, self.calibration)

    def _read_sample(self) -> tuple[float, r.Sample | None]:
        """One reading (blocking) and its clock time; a failed, implausible or jumpy one is
        re-read once.

        A jump that the re-read confirms is real motion (the chip's output registers change at
        100 Hz, so two reads a moment apart agree); one the re-read contradicts was a corrupted
        read (the Pi's clock-stretching bug) and is counted in ``suspect_readings``.
        """
        stamp = self.clock.now()
        first = self._read_once()
        why = "I/O error" if first is None else r.check_sample(first, fusion_running=True)
        if why is None and first is not None and self._prev is not None:
            why = r.sample_jump(self._prev, first)
        if why is None:
            self._note(True)
            self._prev = first
            return stamp, first
        second = self._read_once()
        if second is not None and r.check_sample(second, fusion_running=True) is None:
            first_plausible = first is not None and r.check_sample(first, True) is None
            if first_plausible and first is not None and r.sample_jump(first, second) is None:
                self._note(True)  # a real, confirmed change
                self._prev = second
                return stamp, second
            if first is not None:
                self.counters["suspect_readings"] += 1
                self._note(False)
            if self._prev is None or r.sample_jump(self._prev, second) is None:
                self._prev = second
                return stamp, second
        elif first is not None:
            self.counters["suspect_readings"] += 1
            self._note(False)
        self.counters["dropped_samples"] += 1
        log.debug("BNO055 reading dropped: %s", why)
        return stamp, None

    def _read_paced(
        self, n: int, period_s: float, due: float
    ) -> tuple[list[tuple[float, r.Sample | None]], float]:
        """``n`` readings at ``due``, ``due + period_s``, ... in the I/O thread, which paces
        them itself (so the event loop wakes once per trip); returns them and the next due
        time. A late thread skips the missed slots instead of bunching reads."""
        out = []
        for _ in range(n):
            delay = due - self.clock.now()
            if delay > 0:
                wall_sleep(delay)
            elif delay < -period_s:
                due = self.clock.now()
            out.append(self._read_sample())
            due += period_s
        return out, due

    async def _stream(self) -> None:
        period = 1.0 / self.cfg.rate_hz
        next_check = self.clock.now() + 0.1  # first check (and CALIB_STAT) soon
        consecutive = 0
        due = self.clock.now()
        ticks = None if self.offload else self.clock.every(period)
        while True:
            if ticks is None:
                # Real bus: several readings per trip to the I/O thread.
                readings, due = await self._io(
                    self._read_paced, self.cfg.samples_per_wakeup, period, due
                )
            else:
                # The in-memory fake bus on simulated time: one reading per clock tick, inline.
                await anext(ticks)
                readings = [self._read_sample()]
            for stamp, sample in readings:
                if sample is None:
                    consecutive += 1
                    if consecutive >= self.cfg.max_consecutive_errors:
                        raise ImuFault(
                            f"{consecutive} failed readings in a row from the BNO055 at "
                            f"{self._where()}: re-initialising. If this repeats, {BAUD_FIX}"
                        )
                    continue
                consecutive = 0
                self._check_frozen(sample, stamp)
                self._publish(sample, stamp)
            now = self.clock.now()
            if now >= next_check:
                next_check = now + 1.0
                await self._periodic_checks()
                due = max(due, self.clock.now())

    def _check_frozen(self, sample: r.Sample, stamp: float) -> None:
        """A live chip's readings always differ in their last bits (sensor noise): the same
        reading for ``frozen_timeout_s`` means its output froze (it still answers on the bus),
        which only a re-initialisation cures."""
        limit = self.cfg.frozen_timeout_s
        if limit <= 0.0:
            return
        data = (sample.quat_wxyz, sample.gyro_radps, sample.linear_accel_mps2,
                sample.heading_rad)
        if data != self._last_sample:
            self._last_sample, self._same_since = data, stamp
            return
        if self._same_since is not None and stamp - self._same_since >= limit:
            self.counters["frozen"] += 1
            self._last_sample, self._same_since = None, None
            raise ImuFault(
                f"the BNO055 at {self._where()} has sent the same reading for {limit:g} s: its "
                "output froze; re-initialising it (if this repeats, power-cycle it)")

    async def _periodic_checks(self) -> None:
        try:
            chip_id = await self._read_expect(r.Reg.CHIP_ID, r.CHIP_ID_VALUE)
            mode = await self._read_expect(r.Reg.OPR_MODE, self._mode, 0x0F)
        except OSError:
            self._note(False)
            return
        if chip_id != r.CHIP_ID_VALUE or (mode & 0x0F) != self._mode:
            self.counters["reinits"] += 1
            raise ImuFault(
                f"the BNO055 at {self._where()} lost its configuration (chip id 0x{chip_id:02X},"
                f" mode 0x{mode & 0x0F:X}): it reset (power dip?) — re-initialising"
            )
        with contextlib.suppress(OSError):
            a = await self._read(r.Reg.CALIB_STAT)
            b = await self._read(r.Reg.CALIB_STAT)
            if a == b:  # two equal reads: not garbage
                self.calibration = r.decode_calib_stat(a)
        if self._fully_calibrated(self.calibration) and not self._saved_this_session:
            self._saved_this_session = True
            try:
                await self._save_calibration()
            except OSError as exc:
                log.warning("could not save the BNO055 calibration: %s", exc)
        self._assess_errors()

    def _publish(self, sample: r.Sample, now: float) -> None:
        quat = r.chip_quat_to_rep103(sample.quat_wxyz)
        imu = Imu(
            stamp=now,
            orientation_xyzw=quat if quat is not None else (0.0, 0.0, 0.0, 1.0),
            angular_velocity_radps=sample.gyro_radps,
            linear_acceleration_mps2=sample.linear_accel_mps2,
            orientation_valid=quat is not None,
            calibration=sample.calibration,
            frame_id="imu_link",
        )
        self.counters["samples"] += 1
        self.bus.publish(IMU, imu)
        self.reporter.recovered(now)

    # --- health -------------------------------------------------------------------------------
    def _note(self, ok: bool) -> None:
        now = self.clock.now()
        self._recent.append((now, ok))
        while self._recent and self._recent[0][0] < now - 10.0:
            self._recent.popleft()

    def _assess_errors(self) -> None:
        total = len(self._recent)
        bad = sum(1 for _, ok in self._recent if not ok)
        if total and bad / total > self.cfg.error_rate_warn:
            self.reporter.set_state(
                "degraded",
                f"{bad} of {total} BNO055 reads in the last 10 s failed or were corrupted "
                f"(counted and dropped): {BAUD_FIX}",
            )
        elif self.state == "degraded":
            self.reporter.set_state("ok", self._running())
        else:
            self.reporter.publish()

    def _calibration_counters(self) -> dict[str, float]:
        sys_, gyr, acc, mag = self.calibration
        return {"calibration_sys": sys_, "calibration_gyr": gyr, "calibration_acc": acc,
                "calibration_mag": mag}

    def _report_down(self, exc: Exception) -> None:
        self.reporter.lost(str(exc))
