"""BNO055: register encoding (vectors, round trips), the fake I2C bus, and the real driver on
the fake bus with every fault knob (wrong address, missing chip, wrong id, clock-stretching
garbage, I/O errors, a chip reset), calibration saved and restored."""

from __future__ import annotations

import asyncio
import errno
import json
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import ImuConfig
from curio.core.geometry import quat_to_yaw, yaw_to_quat
from curio.core.messages import DriverHealth, Imu
from curio.core.topics import EVENTS, HEALTH, IMU, make_bus
from curio.drivers.bno055 import protocol as r
from curio.drivers.bno055.driver import Bno055Driver
from curio.drivers.bno055.emulator import Bno055Emulator


def truth(t: float) -> Imu:
    """A rover turning at 0.2 rad/s from yaw 0.5, accelerating forward at 0.3 m/s²."""
    return Imu(t, yaw_to_quat(0.5 + 0.2 * t), (0.0, 0.0, 0.2), (0.3, 0.0, 0.0), True)


# --- registers --------------------------------------------------------------------------------
def test_scales_follow_unit_sel() -> None:
    assert r.gyro_lsb_per_unit(r.UNIT_GYR_RPS) == 900.0
    assert r.gyro_lsb_per_unit(0) == pytest.approx(16 * 180 / math.pi)  # 16 LSB per dps
    assert r.accel_lsb_per_unit(0) == 100.0
    assert r.CURIO_UNIT_SEL == 0x06


def test_decode_vector() -> None:
    # 0x14..0x2D: gyro z = 900 LSB = 1 rad/s; heading 900 = 1 rad; quaternion w = 16384 = 1;
    # LIA x = 100 = 1 m/s².
    data = bytes.fromhex(
        "0000 0000 8403  8403 0000 0000  0040 0000 0000 0000  6400 0000 0000".replace(" ", "")
    )
    s = r.decode_block(data, r.CURIO_UNIT_SEL, (3, 3, 3, 3))
    assert s.gyro_radps == (0.0, 0.0, 1.0)
    assert s.heading_rad == 1.0
    assert s.quat_wxyz == (1.0, 0.0, 0.0, 0.0)
    assert s.linear_accel_mps2 == (1.0, 0.0, 0.0)
    assert s.calibration == (3, 3, 3, 3)
    # In dps mode the same 16 LSB are 1 dps.
    dps = r.decode_block(bytes.fromhex("0000" * 2 + "1000" + "00" * 20), 0x00)
    assert dps.gyro_radps[2] == pytest.approx(math.radians(1.0))
    assert r.decode_calib_stat(0b11_10_01_00) == (3, 2, 1, 0)


fl = st.floats(-3.0, 3.0, allow_nan=False)


@given(st.floats(-math.pi, math.pi), fl, fl, fl, st.sampled_from([0x00, 0x06, 0x01, 0x07]))
def test_sample_roundtrip(yaw: float, wz: float, ax: float, ay: float, unit_sel: int) -> None:
    q = r.rep103_to_chip_quat(yaw_to_quat(yaw))
    s = r.Sample(q, (0.0, 0.1, wz), (ax, ay, 0.0), yaw % (2 * math.pi))
    back = r.decode_block(r.encode_block(s, unit_sel), unit_sel)
    assert back.gyro_radps[2] == pytest.approx(wz, abs=2 / r.gyro_lsb_per_unit(unit_sel))
    assert back.linear_accel_mps2[0] == pytest.approx(ax, abs=2 / r.accel_lsb_per_unit(unit_sel))
    rep = r.chip_quat_to_rep103(back.quat_wxyz)
    assert rep is not None
    assert math.cos(quat_to_yaw(rep) - yaw) == pytest.approx(1.0, abs=1e-6)
    assert r.check_sample(back, fusion_running=True) is None


def test_check_sample_catches_garbage() -> None:
    good = r.Sample((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.1), (0.0,) * 3)
    zero = r.Sample((0.0,) * 4, (0.0,) * 3, (0.0,) * 3)
    assert r.check_sample(good, True) is None
    assert r.check_sample(zero, True) == "all-zero quaternion"
    flipped = r.Sample((1.0 + 256 / 16384, 0.0, 0.0, 0.0), good.gyro_radps, (0.0,) * 3)
    assert "norm" in (r.check_sample(flipped, True) or "")
    jumpy = r.Sample(good.quat_wxyz, (0.0, 0.0, 0.1 + 256 / 900), (0.0,) * 3)
    assert r.sample_jump(good, jumpy) == "angular-rate jump"
    assert r.sample_jump(good, good) is None


def test_calibration_profile_json_and_checks() -> None:
    data = bytes(range(20)) + (700).to_bytes(2, "little", signed=True)
    prof = r.CalibrationProfile(data)
    assert r.CalibrationProfile.from_json(json.loads(json.dumps(prof.to_json()))) == prof
    assert prof.values[10] == 700
    bad = r.CalibrationProfile(bytes(22))
    assert "MAG_RADIUS" in (bad.problem() or "")
    with pytest.raises(ValueError, match="22 bytes"):
        r.CalibrationProfile(b"\x00")


# --- fake bus ---------------------------------------------------------------------------------
def test_fake_bus_register_map() -> None:
    t = [0.0]
    bus = Bno055Emulator(truth, lambda: t[0], power_on_s=0.4)
    with pytest.raises(OSError) as exc:
        bus.read_byte_data(0x28, r.Reg.CHIP_ID)  # still booting: no ACK
    assert exc.value.errno == errno.EREMOTEIO
    t[0] = 0.5
    assert bus.read_i2c_block_data(0x28, 0x00, 7) == [0xA0, 0xFB, 0x32, 0x0F, 0x11, 0x03, 0x15]
    assert bus.read_byte_data(0x28, r.Reg.UNIT_SEL) == 0x80  # POR value
    with pytest.raises(OSError):
        bus.read_byte_data(0x29, r.Reg.CHIP_ID)  # nothing at 0x29
    bus.write_byte_data(0x28, r.Reg.UNIT_SEL, 0x06)
    bus.write_byte_data(0x28, r.Reg.OPR_MODE, r.Mode.IMU)
    t[0] = 0.6
    assert bus.read_byte_data(0x28, r.Reg.SYS_STATUS) == 5
    bus.write_byte_data(0x28, r.Reg.UNIT_SEL, 0x00)  # not in CONFIG: ignored, SYS_ERR 6
    assert bus.read_byte_data(0x28, r.Reg.UNIT_SEL) == 0x06
    assert bus.read_byte_data(0x28, r.Reg.SYS_ERR) == 6
    gz = int.from_bytes(bytes(bus.read_i2c_block_data(0x28, 0x18, 2)), "little", signed=True)
    assert gz == round(0.2 * 900)
    bus.write_byte_data(0x28, r.Reg.PAGE_ID, 1)
    assert bus.read_i2c_block_data(0x28, 0x08, 4) == [0x0D, 0x6D, 0x38, 0x00]
    bus.write_byte_data(0x28, r.Reg.PAGE_ID, 0)
    bus.write_byte_data(0x28, r.Reg.SYS_TRIGGER, 0x20)  # reset: silent for 0.65 s
    t[0] = 1.0
    with pytest.raises(OSError):
        bus.read_byte_data(0x28, r.Reg.CHIP_ID)
    t[0] = 1.3
    assert bus.read_byte_data(0x28, r.Reg.OPR_MODE) == 0 and bus.resets == 1


# --- driver on the fake bus (simulated time) ---------------------------------------------------
class Rig:
    def __init__(self, tmp_path: Path, *, fake_address: int = 0x28, mode: str = "imu",
                 offload: bool = False, fake: Bno055Emulator | None = None,
                 clock: SimClock | None = None) -> None:
        self.clock = clock or SimClock()
        self.bus: Bus = make_bus()
        self.fake = fake or Bno055Emulator(truth, self.clock.now, address=fake_address)
        self.path = tmp_path / "bno055_calibration.json"
        cfg = ImuConfig(mode=mode, reconnect_s=0.5)  # type: ignore[arg-type]
        self.driver = Bno055Driver(cfg, self.clock, self.bus, calibration_path=self.path,
                                   open_bus=self.fake.reopen, offload=offload)
        self.imu = self.bus.subscribe(IMU, maxsize=10_000)
        self.events = self.bus.subscribe(EVENTS)
        self.health = self.bus.subscribe(HEALTH, maxsize=1000)

    async def run_for(self, seconds: float) -> None:
        self.bus.bind_loop(asyncio.get_running_loop())
        task = asyncio.create_task(self.driver.run())
        try:
            await self.clock.advance(seconds)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events.drain()]

    def healths(self) -> list[DriverHealth]:
        return [h for h in self.health.drain() if h.name == "imu"]


async def test_driver_publishes_rep103_imu(tmp_path: Path) -> None:
    rig = Rig(tmp_path, mode="ndof")
    await rig.run_for(3.0)
    msgs = rig.imu.drain()
    assert 230 <= len(msgs) <= 270  # 100 Hz once booted (0.4 s POR + init)
    for m in msgs[5:]:
        assert m.frame_id == "imu_link"
        assert m.orientation_valid
        yaw_true = 0.5 + 0.2 * m.stamp
        assert math.cos(quat_to_yaw(m.orientation_xyzw) - yaw_true) > math.cos(0.01)
        assert m.angular_velocity_radps[2] == pytest.approx(0.2, abs=0.002)
        assert m.linear_acceleration_mps2[0] == pytest.approx(0.3, abs=0.011)
    assert msgs[-1].calibration == (1, 3, 1, 1)  # gyro first; accel and mag take longer
    assert msgs[0].calibration[1] == 0
    assert rig.driver.state == "ok"


async def test_imu_mode_heading_is_relative(tmp_path: Path) -> None:
    rig = Rig(tmp_path, mode="imu")
    await rig.run_for(1.0)
    msgs = rig.imu.drain()
    first = msgs[0]
    # Heading starts near 0 at the mode switch and turns with the rover (counter-clockwise).
    assert abs(quat_to_yaw(first.orientation_xyzw)) < 0.05
    dyaw = quat_to_yaw(msgs[-1].orientation_xyzw) - quat_to_yaw(first.orientation_xyzw)
    assert dyaw == pytest.approx(0.2 * (msgs[-1].stamp - first.stamp), abs=0.01)


async def test_calibration_saved_then_restored(tmp_path: Path) -> None:
    rig = Rig(tmp_path, mode="imu")
    await rig.run_for(7.0)
    assert rig.path.is_file()
    saved = json.loads(rig.path.read_text())
    assert bytes.fromhex(saved["profile_hex"]) == rig.fake.true_profile
    assert "driver.imu_calibration_saved" in rig.kinds()
    # A fresh start (new chip power-on) restores it: calibrated at once.
    rig2 = Rig(tmp_path, mode="imu")
    await rig2.run_for(1.0)
    assert rig2.driver.counters["calibration_restored"] == 1
    assert rig2.imu.drain()[-1].calibration[1:3] == (3, 3)


async def test_wrong_address_says_what_to_check(tmp_path: Path) -> None:
    rig = Rig(tmp_path, fake_address=0x29)
    await rig.run_for(3.0)
    assert rig.driver.state == "error"
    msg = rig.driver.message
    assert "0x28" in msg and "0x29" in msg and "i2cdetect -y 1" in msg and "wiring" in msg
    assert "driver.imu_lost" in rig.kinds()
    assert len(rig.imu) == 0


async def test_missing_chip_and_wrong_id(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    rig.fake.faults.missing = True
    await rig.run_for(3.0)
    assert "no BNO055 answers" in rig.driver.message
    rig2 = Rig(tmp_path)
    rig2.fake.faults.chip_id = 0x68  # an MPU-6050 at that address, say
    await rig2.run_for(3.0)
    assert "0x68" in rig2.driver.message and "0xA0" in rig2.driver.message
    assert "i2c_arm_baudrate" in rig2.driver.message


async def test_no_i2c_device_node(tmp_path: Path) -> None:
    def missing() -> Bno055Emulator:
        raise FileNotFoundError("/dev/i2c-1")

    clock = SimClock()
    bus = make_bus()
    drv = Bno055Driver(ImuConfig(), clock, bus, calibration_path=tmp_path / "c.json",
                       open_bus=missing, offload=False)
    task = asyncio.create_task(drv.run())
    await clock.advance(0.5)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert "raspi-config" in drv.message and drv.state == "error"


async def test_clock_stretching_garbage_is_filtered(tmp_path: Path) -> None:
    rig = Rig(tmp_path, mode="ndof")
    f = rig.fake.faults
    f.bit7_rate, f.zero_rate, f.lsb_flip_rate, f.io_error_rate = 0.05, 0.02, 0.05, 0.02
    await rig.run_for(6.0)
    msgs = rig.imu.drain()
    assert len(msgs) > 450  # most samples survive
    for m in msgs:
        yaw_true = 0.5 + 0.2 * m.stamp
        assert math.cos(quat_to_yaw(m.orientation_xyzw) - yaw_true) > math.cos(0.02)
        assert m.angular_velocity_radps[2] == pytest.approx(0.2, abs=0.01)
        assert m.linear_acceleration_mps2[0] == pytest.approx(0.3, abs=0.05)
    c = rig.driver.counters
    assert c["i2c_errors"] > 0 and c["suspect_readings"] > 0 and c["dropped_samples"] >= 0
    assert rig.driver.state == "degraded"
    assert "i2c_arm_baudrate=10000" in rig.driver.message


async def test_chip_reset_is_reinitialised(tmp_path: Path) -> None:
    rig = Rig(tmp_path, mode="ndof")
    rig.bus.bind_loop(asyncio.get_running_loop())
    task = asyncio.create_task(rig.driver.run())
    try:
        await rig.clock.advance(2.0)
        rig.fake.write_byte_data(0x28, r.Reg.SYS_TRIGGER, 0x20)  # brown-out / reset
        await rig.clock.advance(4.0)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    assert rig.fake.mode == r.Mode.NDOF  # configured again
    assert rig.driver.counters["sessions"] >= 2
    kinds = rig.kinds()
    assert "driver.imu_lost" in kinds and "driver.imu_recovered" in kinds
    assert rig.imu.drain()[-1].stamp > 5.9
    assert rig.driver.state in ("ok", "degraded")


async def test_threaded_io_on_real_clock(tmp_path: Path) -> None:
    """The real configuration: bus calls in a worker thread, wall-clock time."""
    from curio.core.clock import RealClock

    clock = RealClock()
    bus = make_bus()
    bus.bind_loop(asyncio.get_running_loop())
    fake = Bno055Emulator(truth, clock.now, power_on_s=0.05)
    drv = Bno055Driver(ImuConfig(), clock, bus, calibration_path=tmp_path / "c.json",
                       open_bus=fake.reopen, offload=True)
    sub = bus.subscribe(IMU, maxsize=1000)
    task = asyncio.create_task(drv.run())
    try:
        ok = await clock.wait_until(lambda: len(sub) >= 20, 3.0, 0.01)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    assert ok, drv.message


async def test_a_frozen_output_is_detected_and_the_chip_reinitialised(tmp_path: Path) -> None:
    # Found by curio soak: a BNO055 whose registers stopped changing (it still answers on the
    # bus) went on publishing the same stale reading for ever, with /health ok.
    rig = Rig(tmp_path, mode="ndof")
    rig.bus.bind_loop(asyncio.get_running_loop())
    task = asyncio.create_task(rig.driver.run())
    try:
        await rig.clock.advance(2.0)
        rig.fake.faults.frozen = True
        await rig.clock.advance(6.0)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    assert rig.driver.counters["frozen"] == 1
    assert any(h.state == "error" and "froze" in h.message for h in rig.healths())
    kinds = rig.kinds()
    assert "driver.imu_lost" in kinds and "driver.imu_recovered" in kinds
    msgs = rig.imu.drain()
    assert msgs[-1].stamp > 7.9  # readings again, and they change
    assert msgs[-1].orientation_xyzw != msgs[-20].orientation_xyzw


async def test_i2c_errors_while_configuring_end_the_session_not_the_driver(
        tmp_path: Path) -> None:
    # Found by curio soak (i2c_errors): a write that failed three times during the chip's
    # configuration raised OSError out of the driver, which crashed the IMU part and the rover.
    rig = Rig(tmp_path, mode="ndof")
    rig.fake.faults.io_error_rate = 0.9
    rig.bus.bind_loop(asyncio.get_running_loop())
    task = asyncio.create_task(rig.driver.run())
    try:
        await rig.clock.advance(5.0)
        assert not task.done(), task.exception() if task.done() else None
        rig.fake.faults.io_error_rate = 0.0
        await rig.clock.advance(5.0)
        assert not task.done()
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    assert rig.driver.counters["sessions"] >= 2
    assert any(h.state == "error" for h in rig.healths())
    assert rig.driver.state == "ok", rig.driver.message
    assert rig.imu.drain()[-1].stamp > 9.0
