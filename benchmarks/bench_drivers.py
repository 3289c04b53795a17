"""Device drivers' CPU cost at full data rates, against the emulators, in real time.

The subject is the driver side of the rover as it runs on the Pi: the RPLidar driver at 10
revolutions/s (360 samples each), the Arduino base driver with servo feedback at 30 Hz and
commands at its configured rate, and the BNO055 driver at 100 Hz (smbus calls in a worker
thread, as on the Pi). Target: **< 5 % of one core in total**.

The emulators are kept out of the figure:

* the Arduino and RPLidar emulators run in two child processes (``curio emulate arduino``,
  ``curio emulate rplidar``, each with its simulated world in real time) and their CPU time is
  reported separately (``emulators_cpu_fraction``);
* the BNO055's fake I2C bus necessarily runs in this process (it stands for the I2C hardware):
  the CPU time spent inside its calls (and in the world's ``imu_sample``) is measured with the
  thread CPU clock and subtracted.

Each driver is also measured alone (rows ``curio:lidar``, ``curio:arduino``, ``curio:imu``),
and a ``baseline:empty-loop-100Hz`` row shows what this machine charges for an asyncio loop that
does nothing but wake up 100 times a second (scheduling overhead, high on a loaded VM).

Options (``--set``): ``duration=10`` seconds measured per phase (after a 3 s warm-up).
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from curio.commands.bench import BenchOptions
from curio.core.clock import RealClock
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, IMU, SCAN, WHEELS, make_bus
from curio.drivers.arduino.driver import ArduinoBase
from curio.drivers.bno055.driver import Bno055Driver
from curio.drivers.bno055.emulator import Bno055Emulator
from curio.drivers.rplidar.driver import RplidarDriver
from curio.robot import RobotModel
from curio.sim.world import World

WARMUP_S = 3.0


class TimedFakeBus:
    """The fake BNO055 bus with the CPU time spent inside it accumulated (thread CPU clock)."""

    def __init__(self, inner: Bno055Emulator) -> None:
        self.inner = inner
        self.cpu_s = 0.0

    def _timed(self, name: str, *args: Any) -> Any:
        t0 = time.thread_time()
        try:
            return getattr(self.inner, name)(*args)
        finally:
            self.cpu_s += time.thread_time() - t0

    def read_byte_data(self, addr: int, reg: int, force: bool | None = None) -> int:
        return int(self._timed("read_byte_data", addr, reg))

    def write_byte_data(self, addr: int, reg: int, value: int, force: bool | None = None) -> None:
        self._timed("write_byte_data", addr, reg, value)

    def read_i2c_block_data(self, addr: int, reg: int, length: int,
                            force: bool | None = None) -> list[int]:
        return list(self._timed("read_i2c_block_data", addr, reg, length))

    def write_i2c_block_data(self, addr: int, reg: int, data: list[int],
                             force: bool | None = None) -> None:
        self._timed("write_i2c_block_data", addr, reg, data)

    def close(self) -> None:
        self.inner.closed = True

    def reopen(self) -> TimedFakeBus:
        self.inner.closed = False
        return self


def _spawn(device: str, link: Path, data_dir: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "curio", "emulate", device, "--link", str(link),
         "--set", f'data_dir="{data_dir}"', "--set", "sim.lidar_rate_hz=10"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO_ROOT,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if "emulator on" not in line:
        proc.kill()
        raise RuntimeError(f"curio emulate {device} did not start: {line!r}")
    return proc


def _child_cpu_s(proc: subprocess.Popen[str]) -> float:
    """CPU seconds (user + system) a live child has used so far (/proc/<pid>/stat)."""
    fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = int(fields[11]) + int(fields[12])
    return ticks / os.sysconf("SC_CLK_TCK")


async def _phase(which: set[str], cfg: Config, links: dict[str, Path], duration_s: float,
                 procs: dict[str, subprocess.Popen[str]]) -> dict[str, Any]:
    clock = RealClock()
    bus = make_bus()
    bus.bind_loop(asyncio.get_running_loop())
    tasks: list[asyncio.Task[None]] = []
    fake: TimedFakeBus | None = None
    drivers: list[Any] = []
    if "lidar" in which:
        lidar = RplidarDriver(cfg.drivers.lidar, clock, bus, port=str(links["rplidar"]))
        drivers.append(lidar)
        tasks.append(asyncio.create_task(lidar.run()))
    if "arduino" in which:
        base = ArduinoBase(cfg.drivers.arduino, RobotModel.from_config(cfg.robot), bus, clock,
                           port=str(links["arduino"]))
        drivers.append(base)
        tasks.append(asyncio.create_task(base.run()))

        async def teleop() -> None:
            while True:
                bus.publish(CMD_VEL, Twist(clock.now(), 0.1, 0.2, source="bench"))
                await clock.sleep(0.1)

        tasks.append(asyncio.create_task(teleop()))
    if "imu" in which:
        world = World.from_config(cfg)
        fake = TimedFakeBus(Bno055Emulator(world.imu_sample, clock.now, power_on_s=0.0))
        imu = Bno055Driver(cfg.drivers.imu, clock, bus,
                           calibration_path=cfg.data_path("bench_bno055.json"),
                           open_bus=fake.reopen, offload=True)
        drivers.append(imu)
        tasks.append(asyncio.create_task(imu.run()))
    subs = {name: bus.subscribe(topic, maxsize=100_000)
            for name, topic in (("scan", SCAN), ("imu", IMU), ("wheels", WHEELS))}
    await clock.sleep(WARMUP_S)
    for sub in subs.values():
        sub.drain()
    fake_cpu0 = fake.cpu_s if fake else 0.0
    child0 = {k: _child_cpu_s(p) for k, p in procs.items()}
    cpu0, wall0 = time.process_time(), time.perf_counter()
    await clock.sleep(duration_s)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    fake_cpu = (fake.cpu_s - fake_cpu0) if fake else 0.0
    child = {k: _child_cpu_s(p) - child0[k] for k, p in procs.items()}
    counts = {k: len(s.drain()) for k, s in subs.items()}
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    for drv in drivers:
        close = getattr(drv, "close", None)
        if close is not None:
            await close()
    await asyncio.sleep(0.5)  # let the transports finish closing (their ports are locked)
    emulators = fake_cpu + sum(child[k] for k in child if k in _devices(which))
    driver_cpu = cpu - fake_cpu
    return {
        "cpu_fraction": round(driver_cpu / wall, 4),
        "cpu_ms_per_s": round(1000 * driver_cpu / wall, 2),
        "emulators_cpu_fraction": round(emulators / wall, 4),
        "lidar_hz": round(counts["scan"] / wall, 1),
        "imu_hz": round(counts["imu"] / wall, 1),
        "wheels_hz": round(counts["wheels"] / wall, 1),
        "wall_s": round(wall, 2),
    }


async def _baseline(duration_s: float) -> dict[str, Any]:
    """What this machine charges for an event loop that only wakes up 100 times a second."""

    async def tick() -> None:
        while True:
            await asyncio.sleep(0.01)

    task = asyncio.create_task(tick())
    await asyncio.sleep(1.0)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    await asyncio.sleep(duration_s)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    task.cancel()
    return {"cpu_fraction": round(cpu / wall, 4), "cpu_ms_per_s": round(1000 * cpu / wall, 2),
            "wall_s": round(wall, 2)}


def _devices(which: set[str]) -> set[str]:
    return {"rplidar" if w == "lidar" else w for w in which if w != "imu"}


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Measure all drivers together, then each alone; one row per phase."""
    duration_s = float(opts.extra.get("duration", 10))
    rows: list[dict[str, Any]] = []
    rows.append({"subject": "baseline:empty-loop-100Hz", **asyncio.run(_baseline(duration_s))})
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(REPO_ROOT / "config.toml", [f'data_dir="{tmp}"'])
        links = {"rplidar": Path(tmp) / "lidar", "arduino": Path(tmp) / "arduino"}
        procs = {dev: _spawn(dev, links[dev], tmp) for dev in ("rplidar", "arduino")}
        try:
            for label, which in (("curio", {"lidar", "arduino", "imu"}),
                                 ("curio:lidar", {"lidar"}),
                                 ("curio:arduino", {"arduino"}),
                                 ("curio:imu", {"imu"})):
                row = {"subject": label}
                row.update(asyncio.run(_phase(which, cfg, links, duration_s, procs)))
                if label == "curio":
                    row["target_cpu_fraction"] = 0.05
                    row["meets_target"] = row["cpu_fraction"] < 0.05
                rows.append(row)
        finally:
            for proc in procs.values():
                proc.terminate()
                proc.wait(10)
    return rows
