"""A byte-exact RPLidar A1 on a pseudo-terminal, fed by a scan source (the simulator world).

The emulator behaves as hardware.md §7.3 describes the A1M8: it answers GET_INFO (model 0x18,
firmware 1.29, hardware 7), GET_HEALTH and GET_SAMPLERATE in idle; SCAN and FORCE_SCAN send the
descriptor ``A5 5A 05 00 00 40 81`` and then stream 5-byte nodes, one revolution per
``1 / rate_hz`` seconds of the injected clock, in ``chunks_per_rev`` writes; STOP stops the
stream; RESET stops it, clears a protection stop and prints the ASCII banner. Requests with a
bad checksum are ignored. SET_MOTOR_PWM is ignored (the A1 has no accessory board).

Each revolution comes from ``scan_source(stamp)`` (``world.cast_scan``), a ``LaserScan`` in the
``laser`` frame; beams are turned into raw clockwise angles (``raw = pi - laser``, hardware.md
§5.5) with a little jitter, sorted from the raw 0°, and coded with the start flag on the first
node. No return, ``nan`` or out-of-range beams become distance 0 with quality 0.

Motor: the A1's motor follows the DTR line, which a pty cannot carry; :meth:`set_motor` is the
hook that stands for it (``motor_on`` at start). Nodes flow only ``spin_up_s`` after the motor
started.

Fault knobs (:attr:`faults` and methods): :meth:`unplug` / :meth:`replug` (the device node
vanishes and comes back), ``faults.stalled`` (scanning, but no bytes come out),
:meth:`protection_stop` (health ``error`` until RESET; the stream stops as the A1's does),
``faults.garbage_bytes_per_rev`` and :meth:`inject_garbage` (random bytes inside the stream).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from curio.core.clock import Clock, SimClock
from curio.core.config import Config
from curio.core.messages import LaserScan
from curio.core.parts import Part
from curio.drivers.pty import BytePacer, PtyDevice
from curio.drivers.rplidar import protocol as p

__all__ = ["RplidarEmulator", "RplidarFaults", "ScanWorld"]

BANNER = b"RP LIDAR System.\r\nFirmware Ver 1.29 - rc2, HW Ver 7\r\nModel: 18\r\n"


class ScanWorld(Protocol):
    """What the emulator needs from the simulator's world."""

    def cast_scan(self, stamp: float) -> LaserScan:
        """One revolution seen at clock time ``stamp``, ``laser`` frame."""
        ...


@dataclass
class RplidarFaults:
    """Fault knobs (change them at any time).

    Attributes:
        stalled: the device keeps "scanning" but sends nothing (a stalled stream).
        garbage_bytes_per_rev: random bytes inserted at a random place of every revolution.
        health_status: what GET_HEALTH answers (0 good, 1 warning, 2 protection stop).
        health_error_code: the u16 error code in GET_HEALTH.
    """

    stalled: bool = False
    garbage_bytes_per_rev: int = 0
    health_status: int = 0
    health_error_code: int = 0


class RplidarEmulator:
    """An RPLidar A1M8 serving on a pty.

    Args:
        scan_source: returns the revolution seen at a clock time (``world.cast_scan``).
        clock: the application clock (revolution timing).
        rate_hz: revolutions per second (the A1 does 1–10; typical 5.5).
        chunks_per_rev: writes per revolution (a real device streams continuously).
        spin_up_s: delay between motor start and the first node.
        seed: jitter and quality randomness.
        link_dir: where the stable symlink ``curio-lidar`` is made (a temp dir by default).
        motor_on: the motor's state at start (a pty has no DTR line).
        angle_offset_rad: the mounting offset the driver is configured with (inverse applied).
    """

    def __init__(
        self,
        scan_source: Callable[[float], LaserScan],
        clock: Clock,
        *,
        rate_hz: float = 10.0,
        chunks_per_rev: int = 10,
        spin_up_s: float = 0.2,
        seed: int = 0,
        link_dir: Path | None = None,
        motor_on: bool = True,
        angle_offset_rad: float = 0.0,
        name: str = "curio-lidar",
    ) -> None:
        if not 0.5 <= rate_hz <= 20.0:
            raise ValueError(f"rate_hz must be within 0.5..20, got {rate_hz}")
        self.scan_source = scan_source
        self.clock = clock
        self.rate_hz = rate_hz
        self.chunks_per_rev = max(1, chunks_per_rev)
        self.spin_up_s = spin_up_s
        self.angle_offset_rad = angle_offset_rad
        self.faults = RplidarFaults()
        self.info = p.DeviceInfo(0x18, 29, 1, 7, bytes(range(0x10, 0x20)))
        self._rng = np.random.default_rng(seed)
        self._parser = p.RequestParser()
        self.device = PtyDevice(name, self._on_bytes, link_dir)
        self.scanning = False
        self.motor_on = motor_on
        self._motor_since = clock.now() - (spin_up_s if motor_on else 0.0)
        self._pending_garbage = 0
        self._tasks: set[asyncio.Task[None]] = set()
        self.revolutions_sent = 0
        self.requests: list[int] = []
        #: holds a simulated clock until the driver has read our bytes (see :meth:`pair`)
        self.pacer = BytePacer(clock, lambda: self.device.bytes_written)

    @classmethod
    def for_world(cls, world: ScanWorld, clock: Clock, cfg: Config, seed: int,
                  link: Path | None = None) -> RplidarEmulator:
        """The lidar in the simulator's ``world`` (emulated mode, ``curio emulate rplidar``).

        Args:
            world: the simulator's world (``cast_scan``).
            clock: the application clock.
            cfg: the configuration: ``sim.lidar_rate_hz`` and the driver's
                ``drivers.lidar.angle_offset_rad`` (undone here, so the driver sees the world).
            seed: jitter and quality randomness.
            link: the device path to serve (default: ``curio-lidar`` in a temp dir).
        """
        return cls(world.cast_scan, clock, rate_hz=cfg.sim.lidar_rate_hz, seed=seed,
                   link_dir=link.parent if link else None,
                   name=link.name if link else "curio-lidar",
                   angle_offset_rad=cfg.drivers.lidar.angle_offset_rad)

    def parts(self) -> list[Part]:
        """What runs the emulator: its revolution stream."""
        return [Part("lidar-emulator", run=self.run, close=self.close)]

    # --- life cycle ---------------------------------------------------------------------------
    @property
    def path(self) -> str:
        """The stable device path a driver opens (a symlink to the current pty)."""
        return self.device.path

    def open(self) -> None:
        """Create the pty (on the running loop)."""
        self.device.open()

    async def run(self) -> None:
        """Serve until cancelled: stream revolutions while scanning."""
        self.open()
        period = 1.0 / (self.rate_hz * self.chunks_per_rev)
        chunks: list[bytes] = []
        k = 0
        async for now in self.clock.every(period):
            if not self._streaming(now):
                chunks, k = [], 0
                await self.pacer.settle()  # replies to requests
                continue
            if k == 0:
                chunks = self._revolution_chunks(now)
            if not self.faults.stalled:
                self.device.write(chunks[k])
            k = (k + 1) % self.chunks_per_rev
            await self.pacer.settle()

    async def close(self) -> None:
        """Remove the pty and its link."""
        for task in list(self._tasks):
            task.cancel()
        self.device.close()

    def pair(self, driver: Any) -> None:
        """Pace a fast simulated clock with ``driver`` (an ``RplidarDriver`` on this port).

        On a ``SimClock`` running faster than 2× real time (emulated mode) each side then holds
        the clock until the other has read what it wrote (exact byte counts), so when a scan
        arrives does not depend on how quickly the kernel moves pty bytes. The driver's read
        batching is turned off (it would only make the pacer wait).
        """
        speed = getattr(self.clock, "speed", 1.0)
        if not isinstance(self.clock, SimClock) or (speed is not None and speed <= 2.0):
            return
        self.pacer.peer_received = lambda: int(driver.bytes_received)
        self.pacer.active = lambda: bool(driver.connected)
        driver.pacer.peer_received = lambda: self.device.bytes_read
        driver.pacer.active = lambda: self.device.plugged
        driver.read_interval_s = 0.0

    # --- fault knobs / hooks ------------------------------------------------------------------
    def set_motor(self, on: bool) -> None:
        """The DTR line: True spins the motor (DTR cleared on the real adapter)."""
        if on and not self.motor_on:
            self._motor_since = self.clock.now()
        self.motor_on = on

    def unplug(self) -> None:
        """Pull the USB cable: the device node disappears; an open driver gets EIO."""
        self.scanning = False
        self.device.unplug()

    def replug(self) -> None:
        """Plug it back in: a fresh device in idle state (power-on)."""
        self.scanning = False
        self.faults.health_status = 0
        self.faults.health_error_code = 0
        self._parser = p.RequestParser()
        self.device.replug()

    def protection_stop(self, error_code: int = 0x8001) -> None:
        """Enter protection stop: health ``error``, the stream stops until RESET."""
        self.faults.health_status = 2
        self.faults.health_error_code = error_code
        self.scanning = False

    def inject_garbage(self, n_bytes: int) -> None:
        """Insert ``n_bytes`` random bytes into the stream once."""
        self._pending_garbage += n_bytes

    # --- request handling ---------------------------------------------------------------------
    def _on_bytes(self, data: bytes) -> None:
        written = self.device.bytes_written
        for req in self._parser.feed(data):
            self._handle(req)
        if self.device.bytes_written != written and self.pacer.peer_received is not None:
            self._spawn(self.pacer.settle())  # hold simulated time until the reply is read

    def _handle(self, req: p.Request) -> None:
        self.requests.append(req.cmd)
        cmd = req.cmd
        if cmd == p.Cmd.STOP:
            self.scanning = False
        elif cmd == p.Cmd.RESET:
            self.scanning = False
            self.faults.health_status = 0
            self.faults.health_error_code = 0
            self._spawn(self._banner())
        elif self.scanning:
            return  # while scanning the A1 only listens to STOP and RESET
        elif cmd in (p.Cmd.SCAN, p.Cmd.FORCE_SCAN):
            self.device.write(p.SCAN_DESCRIPTOR)
            if self.faults.health_status != 2:
                self.scanning = True
        elif cmd == p.Cmd.GET_INFO:
            self.device.write(p.INFO_DESCRIPTOR + self.info.encode())
        elif cmd == p.Cmd.GET_HEALTH:
            health = p.HealthStatus(self.faults.health_status, self.faults.health_error_code)
            self.device.write(p.HEALTH_DESCRIPTOR + health.encode())
        elif cmd == p.Cmd.GET_SAMPLERATE:
            self.device.write(p.SAMPLERATE_DESCRIPTOR + (500).to_bytes(2, "little") + (
                250).to_bytes(2, "little"))
        # SET_MOTOR_PWM, GET_ACC_BOARD_FLAG, EXPRESS_SCAN: not on the A1M8 we emulate.

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _banner(self) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            await self.clock.sleep(0.005)
            self.device.write(BANNER)

    # --- streaming ----------------------------------------------------------------------------
    def _streaming(self, now: float) -> bool:
        return (
            self.scanning
            and self.device.plugged
            and self.motor_on
            and now - self._motor_since >= self.spin_up_s
        )

    def _revolution_chunks(self, now: float) -> list[bytes]:
        data = self.encode_revolution(self.scan_source(now))
        garbage = self._pending_garbage + self.faults.garbage_bytes_per_rev
        self._pending_garbage = 0
        if garbage > 0:
            at = int(self._rng.integers(0, len(data) // 5)) * 5 + 2
            noise = self._rng.integers(0, 256, garbage, dtype=np.uint8).tobytes()
            data = data[:at] + noise + data[at:]
        self.revolutions_sent += 1
        n = self.chunks_per_rev
        step = math.ceil(len(data) / n)
        return [data[i * step : (i + 1) * step] for i in range(n)]

    def encode_revolution(self, scan: LaserScan) -> bytes:
        """The node bytes of one revolution showing ``scan`` (start flag on the first node)."""
        ranges = np.asarray(scan.ranges_m, dtype=np.float64)
        angles = scan.angles_rad
        raw = p.laser_to_raw_deg(angles, self.angle_offset_rad)
        raw = (raw + self._rng.uniform(-0.05, 0.05, len(raw))) % 360.0
        order = np.argsort(raw, kind="stable")
        raw, ranges = raw[order], ranges[order]
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(ranges) & (ranges >= 0.15) & (ranges <= 12.0)
        dist_q2 = np.round(np.where(valid, ranges, 0.0) * 4000.0).astype(np.int64)
        quality = np.where(valid, self._rng.integers(10, 48, len(raw)), 0)
        angle_q6 = np.round(raw * 64.0).astype(np.int64) % (360 * 64)
        start = np.zeros(len(raw), dtype=bool)
        if len(start):
            start[0] = True
        return p.encode_nodes(start, quality, angle_q6, dist_q2)
