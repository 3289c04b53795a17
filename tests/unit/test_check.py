"""`curio check` against the emulators: pass and fail cases, fixes, exit codes."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from curio.commands import check
from curio.core.clock import RealClock
from curio.core.config import Config, load_config
from curio.drivers.arduino.emulator import ArduinoEmulator
from curio.drivers.bno055.emulator import Bno055Emulator
from curio.drivers.rplidar.emulator import RplidarEmulator
from curio.sim.world import World

pytestmark = pytest.mark.timeout(60)


class Devices:
    def __init__(self, arduino: ArduinoEmulator, lidar: RplidarEmulator, data_dir: Path) -> None:
        self.arduino, self.lidar, self.data_dir = arduino, lidar, data_dir

    async def check(self, *argv: str) -> tuple[int, str, Any]:
        """Run `curio check` in a thread (it blocks) while the emulators serve on the loop."""
        base = ["--set", f'data_dir="{self.data_dir}"', "--set", "drivers.arduino.boot_wait_s=0.6"]
        import contextlib
        import io

        out = io.StringIO()

        def run() -> int:
            with contextlib.redirect_stdout(out):
                return check.main([*base, *argv])

        rc = await asyncio.to_thread(run)
        return rc, out.getvalue(), None


@pytest.fixture
async def devices(tmp_path: Path) -> AsyncIterator[Devices]:
    cfg = load_config(None, [f'data_dir="{tmp_path}"'])
    clock = RealClock()
    world = World.from_config(cfg)
    arduino = ArduinoEmulator(world, clock, boot_delay_s=0.3)
    arduino.open()
    lidar = RplidarEmulator(world.cast_scan, clock, rate_hz=10.0, spin_up_s=0.0)
    lidar.open()
    tasks = [asyncio.create_task(arduino.run()), asyncio.create_task(lidar.run())]
    yield Devices(arduino, lidar, tmp_path)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    arduino.close()
    await lidar.close()


def row(out: str, name: str) -> str:
    lines = out.splitlines()
    for i, line in enumerate(lines):
        if line.startswith(name + " "):
            fix = lines[i + 1] if i + 1 < len(lines) and "fix:" in lines[i + 1] else ""
            return line + "\n" + fix
    raise AssertionError(f"no row {name!r} in:\n{out}")


async def test_all_devices_pass(devices: Devices) -> None:
    rc, out, _ = await devices.check("--arduino", devices.arduino.port_path,
                                     "--lidar", devices.lidar.path, "--i2c-bus", "emulated")
    assert rc == 0, out
    assert "ok" in row(out, "arduino") and "heartbeat echoed" in row(out, "arduino")
    assert "protocol 1" in row(out, "arduino") and "DISARMED" in row(out, "arduino")
    lidar = row(out, "lidar")
    assert " ok " in lidar and "A1M8" in lidar and "health good" in lidar
    assert "samples/rev" in lidar
    imu = row(out, "imu")
    assert " ok " in imu and "BNO055 at 0x28" in imu and "self-test 0xF" in imu
    assert "all checks passed" in out


async def test_swapped_ports_fail_with_fixes(devices: Devices) -> None:
    rc, out, _ = await devices.check("--arduino", devices.lidar.path,
                                     "--lidar", devices.arduino.port_path, "--skip", "imu")
    assert rc == 1
    assert "FAIL" in row(out, "arduino") and "firmware/README.md" in row(out, "arduino")
    lidar = row(out, "lidar")
    assert "FAIL" in lidar and "really the RPLidar" in lidar
    assert "FAILED: arduino, lidar" in out


async def test_lidar_protection_stop_and_missing_port(devices: Devices, tmp_path: Path) -> None:
    devices.lidar.protection_stop(0x0042)
    rc, out, _ = await devices.check("--lidar", devices.lidar.path, "--skip", "arduino,imu")
    assert rc == 1
    assert "protection stop" in row(out, "lidar") and "0x0042" in row(out, "lidar")
    rc, out, _ = await devices.check("--lidar", str(tmp_path / "nope"), "--skip", "arduino,imu")
    assert rc == 1
    assert "cannot open" in row(out, "lidar") and "udev" in row(out, "lidar")


async def test_stalled_lidar_says_motor(devices: Devices) -> None:
    devices.lidar.faults.stalled = True
    rc, out, _ = await devices.check("--lidar", devices.lidar.path, "--skip", "arduino,imu")
    assert rc == 1
    assert "motor" in row(out, "lidar")


async def test_wrong_imu_address_suggests_the_other(devices: Devices) -> None:
    rc, out, _ = await devices.check("--skip", "arduino,lidar", "--i2c-bus", "emulated",
                                     "--imu-address", "0x29")
    assert rc == 1
    imu = row(out, "imu")
    assert "a BNO055 at 0x28" in imu and "drivers.imu.address = 0x28" in imu


def _imu_cfg(tmp_path: Path) -> Config:
    return load_config(None, [f'data_dir="{tmp_path}"'])


def test_imu_faults(tmp_path: Path) -> None:
    cfg = _imu_cfg(tmp_path)
    clock = RealClock()

    fake = Bno055Emulator(None, clock.now, power_on_s=0.0)
    fake.faults.missing = True
    res = check.check_imu(fake.reopen, cfg, "bus")
    assert res.status == "FAIL" and "nothing answers" in res.detail and "i2cdetect" in res.fix

    fake = Bno055Emulator(None, clock.now, power_on_s=0.0)
    fake.faults.chip_id = 0x68
    res = check.check_imu(fake.reopen, cfg, "bus")
    assert res.status == "FAIL" and "0x68" in res.detail and "i2c_arm_baudrate" in res.fix

    fake = Bno055Emulator(None, clock.now, power_on_s=0.0, seed=4)
    fake.faults.zero_rate = 0.3  # clock-stretching garbage
    res = check.check_imu(fake.reopen, cfg, "bus")
    assert res.status == "warn" and "garbled" in res.detail
    assert "i2c_arm_baudrate=10000" in res.fix

    def no_bus() -> Bno055Emulator:
        raise FileNotFoundError("/dev/i2c-1")

    res = check.check_imu(no_bus, cfg, "/dev/i2c-1")
    assert res.status == "FAIL" and "raspi-config" in res.fix


def test_usage_errors() -> None:
    assert check.main(["--skip", "wheels"]) == 2
    assert check.main(["--i2c-bus", "one", "--skip", "arduino,lidar"]) == 2
    assert check.main(["--imu-address", "forty"]) == 2


def test_port_discovery_by_usb_id() -> None:
    ports = [check.PortInfo("/dev/ttyACM0", 0x2341, 0x0042, "Mega 2560"),
             check.PortInfo("/dev/ttyUSB0", 0x10C4, 0xEA60, "CP2102"),
             check.PortInfo("/dev/ttyUSB1", 0x1A86, 0x7523, "CH340"),
             check.PortInfo("/dev/ttyS0", 0, 0, "")]
    arduinos, clones, lidars = check.find_ports(ports)
    assert [p.device for p in arduinos] == ["/dev/ttyACM0"]
    assert [p.device for p in clones] == ["/dev/ttyUSB1"]
    assert [p.device for p in lidars] == ["/dev/ttyUSB0"]


def test_emulate_usage_errors(tmp_path: Path) -> None:
    from curio.commands import emulate

    assert emulate.main(["rplidar", "--map", str(tmp_path / "missing.yaml")]) == 2
    assert emulate.main(["arduino", "--duration", "0"]) == 2
    assert emulate.main(["rplidar", "--set", "sim.lidar_rate_hz=50"]) == 2  # out of range
    with pytest.raises(SystemExit):
        emulate.main(["bno055"])  # argparse: not an emulated serial device
