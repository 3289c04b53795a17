"""The RPLidar A1 driver: asyncio serial I/O, one ``LaserScan`` per revolution on ``/scan``.

Life cycle of one session (:meth:`RplidarDriver.run` repeats sessions for ever):

1. open the port (``pyserial-asyncio-fast``); a missing device is reported with what to check;
2. STOP, flush, GET_INFO (model, firmware), GET_HEALTH; a protection stop (status 2) is cleared
   with RESET and checked again;
3. motor on (the A1's motor follows DTR: cleared = spinning; a pseudo-terminal has no DTR, so an
   injectable ``motor`` hook is called as well), SCAN, check the descriptor;
4. stream: bytes go through :class:`~curio.drivers.rplidar.protocol.NodeStreamDecoder`
   (resynchronising after bad bytes) and :class:`~curio.drivers.rplidar.protocol.ScanAssembler`;
   each revolution is binned into ``beams`` fixed angles in the ``laser`` frame (``pi - raw``,
   as ``rplidar_ros`` does) and published, stamped with the clock time its first node arrived.

The session ends on an unplugged device (the port reports EIO), on a stall (no revolution for
``stall_timeout_s``) or on an answer that makes no sense; the driver then publishes ``/health``
``error`` with what happened and what to do plus an event ``driver.lidar_lost``, stops
publishing scans — the safety stage stops the rover when the latest scan is older than its
timeout — and starts a new session every ``reconnect_s`` until the lidar is back
(``driver.lidar_recovered``).

Corrupt bytes that the decoder skips do not end a session, but keep ``/health`` ``degraded``
(with the count and what to check) until ``CORRUPT_WINDOW_S`` pass without any, so a flaky
cable shows on the dashboard and in the event log.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import LidarConfig
from curio.core.messages import LaserScan
from curio.core.topics import SCAN
from curio.drivers.health import HealthReporter, ReportsHealth
from curio.drivers.pty import BytePacer
from curio.drivers.rplidar import protocol as p
from curio.drivers.session import Backoff, DeviceFault, SessionLoop, wait_event

__all__ = ["LidarFault", "RplidarDriver"]

log = logging.getLogger("curio.drivers.rplidar")

MotorHook = Callable[[bool], None]


# Corrupt bytes in the stream keep /health degraded this long after the last one, seconds.
CORRUPT_WINDOW_S = 10.0


class LidarFault(DeviceFault):
    """A session-ending problem, phrased for the person who has to fix it."""


class _Proto(asyncio.Protocol):
    def __init__(self, driver: RplidarDriver) -> None:
        self.driver = driver

    def data_received(self, data: bytes) -> None:
        self.driver._on_data(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.driver._on_lost(exc)


class RplidarDriver(ReportsHealth):
    """Talks to an RPLidar A1 and publishes ``/scan``, ``/health`` and events.

    Args:
        cfg: ``drivers.lidar`` (port, baud, stall timeout, beams, angle offset...).
        clock: the application clock.
        bus: the application bus.
        port: overrides ``cfg.port`` (the emulator's pty in emulated mode).
        motor: called with True/False to start/stop the motor where DTR cannot (a pty).
    """

    name = "lidar"

    def __init__(
        self,
        cfg: LidarConfig,
        clock: Clock,
        bus: Bus,
        *,
        port: str | None = None,
        motor: MotorHook | None = None,
    ) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = bus
        self.port = port or cfg.port
        self.motor = motor
        self.info: p.DeviceInfo | None = None
        self.health: p.HealthStatus | None = None
        self.counters: dict[str, float] = {
            "scans": 0,
            "sessions": 0,
            "resync_bytes": 0,
            "stalls": 0,
            "unplugs": 0,
            "resets": 0,
            "short_scans": 0,
            "partial_scans": 0,
        }
        self.reporter = HealthReporter(self.name, clock, bus, log, self.counters)
        self._transport: Any = None
        self.bytes_sent = 0
        self.bytes_received = 0
        self.read_interval_s = cfg.read_interval_s
        #: holds a simulated clock until the emulator has read our bytes (emulated mode)
        self.pacer = BytePacer(clock, lambda: self.bytes_sent)
        self._rx = bytearray()
        self._rx_event = asyncio.Event()
        self._paused = asyncio.Event()
        self._lost = False
        self._mode = "reply"  # reply | descriptor | stream
        self._decoder = p.NodeStreamDecoder()
        self._assembler = p.ScanAssembler(min_nodes=cfg.min_nodes_per_scan,
                                          max_gap_deg=cfg.max_scan_gap_deg)
        self._rev_start: float | None = None
        self._last_scan_at = -math.inf
        self._scanning: tuple[str, str] = ("ok", "scanning")
        self.corrupt_window_s = CORRUPT_WINDOW_S
        self._resync_seen = 0
        self._corrupt_recent = 0
        self._corrupt_last_s: float | None = None

    # --- the long-lived part ------------------------------------------------------------------
    async def run(self) -> None:
        """Run sessions for ever; each failure is reported and retried; ``/health`` every
        second."""
        reconnect_s = self.cfg.reconnect_s
        await SessionLoop(
            self.clock, self._session, self._report_down, Backoff(reconnect_s, reconnect_s),
            after=self._close_port, on_abort=self._shut_down,
            health=self.reporter, health_period_s=1.0,
        ).run()

    async def _shut_down(self) -> None:
        await self._close_port(stop=True)  # shutting down: scanning and motor off

    async def close(self) -> None:
        """Stop scanning and the motor, close the port."""
        await self._close_port(stop=True)

    # --- one session --------------------------------------------------------------------------
    async def _session(self) -> None:
        self.counters["sessions"] += 1
        await self._open()
        await self._stop_and_flush()
        self.info = p.DeviceInfo.decode(
            await self._request(p.Cmd.GET_INFO, p.INFO_DESCRIPTOR, 20, "GET_INFO")
        )
        health = await self._get_health()
        if health.status == p.HealthLevel.ERROR:
            self.reporter.set_state(
                "error",
                f"the lidar reported a protection stop (error code 0x{health.error_code:04X}): "
                "sent RESET; if this repeats the laser or motor needs service",
            )
            await self._reset()
            health = await self._get_health()
            if health.status == p.HealthLevel.ERROR:
                raise LidarFault(
                    f"the lidar stays in protection stop after RESET (error code "
                    f"0x{health.error_code:04X}): power-cycle it; if it persists the laser or "
                    "motor is damaged"
                )
        self._set_motor(True)
        await self._start_scan()
        self._scanning = (
            "degraded" if health.status == p.HealthLevel.WARNING else "ok",
            f"scanning: {self.info.describe()}"
            + (f"; health warning 0x{health.error_code:04X}" if health.status else ""),
        )
        self.reporter.set_state(*self._scanning)
        # Watch the stream until it fails.
        started = self.clock.now()
        poll = min(0.25, self.cfg.stall_timeout_s / 4)
        resumer = asyncio.ensure_future(self._resume_loop())
        try:
            await self._watch(started, poll)
        finally:
            resumer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await resumer

    async def _resume_loop(self) -> None:
        """Batch reads: after each chunk the port is paused for ``read_interval_s`` so bytes
        gather in the kernel buffer (a USB adapter delivers them every millisecond)."""
        while True:
            await self._paused.wait()
            self._paused.clear()
            await self.clock.sleep(self.read_interval_s)
            if self._transport is not None and not self._lost:
                with contextlib.suppress(Exception):
                    self._transport.resume_reading()

    def _check_stream(self, now: float) -> None:
        """Corrupt bytes in the stream (the decoder had to resynchronise): ``degraded`` until
        ``CORRUPT_WINDOW_S`` pass without any, then back to the session's state."""
        seen = self._decoder.resync_bytes
        if seen > self._resync_seen:
            self._corrupt_recent += seen - self._resync_seen
            self._resync_seen = seen
            self._corrupt_last_s = now
            self.reporter.set_state(
                "degraded", f"corrupt bytes in the lidar's stream ({self._corrupt_recent} "
                "dropped while resynchronising in the last seconds; scans go on): check the "
                "USB cable and that drivers.lidar.baud matches the lidar")
        elif self._corrupt_last_s is not None and \
                now - self._corrupt_last_s > self.corrupt_window_s:
            self._corrupt_last_s = None
            self._corrupt_recent = 0
            self.reporter.set_state(*self._scanning)

    async def _watch(self, started: float, poll: float) -> None:
        self._resync_seen = self._decoder.resync_bytes
        while True:
            await self.clock.sleep(poll)
            self._check_stream(self.clock.now())
            if self._lost:
                self.counters["unplugs"] += 1
                raise LidarFault(
                    f"the lidar at {self.port} went away (unplugged?): check its USB cable; "
                    "retrying"
                )
            last = max(self._last_scan_at, started)
            if self.clock.now() - last > self.cfg.stall_timeout_s:
                self.counters["stalls"] += 1
                raise LidarFault(
                    f"no scan for {self.clock.now() - last:.1f} s (stalled stream or motor "
                    "stopped): restarting the lidar; if this repeats check the motor and its "
                    "power (5 V, 1 A)"
                )

    async def _open(self) -> None:
        import serial
        import serial_asyncio_fast

        self._rx.clear()
        self._lost = False
        self._mode = "reply"
        loop = asyncio.get_running_loop()
        try:
            opening = asyncio.ensure_future(serial_asyncio_fast.create_serial_connection(
                loop, lambda: _Proto(self), self.port, baudrate=self.cfg.baud
            ))
            if self.pacer.peer_received is not None:
                # Paced (emulated) mode: the port opens in a worker thread; keep this task
                # runnable meanwhile so simulated time does not move on by a load-dependent
                # amount.
                while not opening.done():
                    await self.clock.sleep(0.0)
            transport, _ = await opening
        except (OSError, serial.SerialException) as exc:
            raise LidarFault(
                f"cannot open the lidar at {self.port} ({exc}): check that it is plugged in, "
                "that the udev rule makes /dev/curio-lidar (deploy/99-curio.rules), that the "
                "user is in the 'dialout' group; run `curio check`"
            ) from exc
        self._transport = transport

    async def _close_port(self, stop: bool = False) -> None:
        transport, self._transport = self._transport, None
        if transport is None:
            return
        if stop and not self._lost:
            with contextlib.suppress(Exception):
                transport.write(p.encode_request(p.Cmd.STOP))
            self._set_motor(False, transport)
        with contextlib.suppress(Exception):
            transport.close()

    @property
    def connected(self) -> bool:
        """True while the port is open and working."""
        return self._transport is not None and not self._lost

    def _write(self, data: bytes) -> None:
        if self._transport is None or self._lost:
            raise LidarFault(f"the lidar at {self.port} is not connected")
        self._transport.write(data)
        self.bytes_sent += len(data)

    async def _stop_and_flush(self) -> None:
        self._mode = "reply"
        self._write(p.encode_request(p.Cmd.STOP))
        await self.pacer.settle()
        await self.clock.sleep(0.01)
        self._rx.clear()
        self._decoder.reset()
        self._assembler.reset()

    async def _reset(self) -> None:
        self.counters["resets"] += 1
        self._write(p.encode_request(p.Cmd.RESET))
        await self.pacer.settle()
        await self.clock.sleep(self.cfg.reset_wait_s)  # the A1 prints a banner meanwhile
        self._rx.clear()

    async def _get_health(self) -> p.HealthStatus:
        health = p.HealthStatus.decode(
            await self._request(p.Cmd.GET_HEALTH, p.HEALTH_DESCRIPTOR, 3, "GET_HEALTH")
        )
        self.health = health
        return health

    async def _request(self, cmd: int, descriptor: bytes, length: int, what: str) -> bytes:
        self._rx.clear()
        self._write(p.encode_request(cmd))
        await self.pacer.settle()
        data = await self._read_exact(p.DESCRIPTOR_LEN + length, what)
        if data[: p.DESCRIPTOR_LEN] != descriptor:
            raise LidarFault(
                f"the device at {self.port} answered {what} with "
                f"{data[: p.DESCRIPTOR_LEN].hex(' ').upper()} instead of "
                f"{descriptor.hex(' ').upper()}: is this port really the RPLidar (not the "
                "Arduino)? Is the baud rate 115200 (A1)?"
            )
        return data[p.DESCRIPTOR_LEN :]

    async def _read_exact(self, n: int, what: str) -> bytes:
        deadline = self.clock.now() + self.cfg.reply_timeout_s
        while len(self._rx) < n:
            if self._lost:
                raise LidarFault(f"the lidar at {self.port} went away during {what}")
            remaining = deadline - self.clock.now()
            if remaining <= 0:
                raise LidarFault(
                    f"no answer to {what} from {self.port} within {self.cfg.reply_timeout_s} s "
                    f"(got {len(self._rx)} of {n} bytes): check the port, the cable and that "
                    "the lidar has power; run `curio check`"
                )
            self._rx_event.clear()
            await wait_event(self.clock, self._rx_event, remaining)
        data = bytes(self._rx[:n])
        del self._rx[:n]
        return data

    async def _start_scan(self) -> None:
        self._rx.clear()
        self._decoder.reset()
        self._assembler.reset()
        self._rev_start = None
        self._mode = "descriptor"
        self._write(p.encode_request(p.Cmd.SCAN))
        await self.pacer.settle()
        deadline = self.clock.now() + self.cfg.reply_timeout_s
        while self._mode == "descriptor":
            if self._lost:
                raise LidarFault(f"the lidar at {self.port} went away while starting to scan")
            if self.clock.now() >= deadline:
                raise LidarFault(
                    f"no SCAN descriptor from {self.port}: the lidar does not start scanning; "
                    "power-cycle it"
                )
            self._rx_event.clear()
            await wait_event(self.clock, self._rx_event, deadline - self.clock.now())

    def _set_motor(self, on: bool, transport: Any = None) -> None:
        transport = transport or self._transport
        ser = getattr(transport, "serial", None) if transport is not None else None
        if ser is not None:
            # A1: DTR cleared = motor spins. A pty has no DTR: ENOTTY.
            with contextlib.suppress(OSError, ValueError, AttributeError):
                ser.dtr = not on
        if self.motor is not None:
            self.motor(on)

    # --- bytes from the port (event-loop callbacks) -------------------------------------------
    def _on_lost(self, exc: Exception | None) -> None:
        self._lost = True
        self._rx_event.set()

    def _on_data(self, data: bytes) -> None:
        self.bytes_received += len(data)
        if self._mode == "stream":
            self._on_stream(data)
            return
        self._rx += data
        if self._mode == "descriptor" and len(self._rx) >= p.DESCRIPTOR_LEN:
            head = bytes(self._rx[: p.DESCRIPTOR_LEN])
            if head == p.SCAN_DESCRIPTOR:
                rest = bytes(self._rx[p.DESCRIPTOR_LEN :])
                self._rx.clear()
                self._mode = "stream"
                self._on_stream(rest)
            else:
                # Leftovers of a previous stream: drop bytes until the descriptor lines up.
                idx = self._rx.find(p.SCAN_DESCRIPTOR[:2], 1)
                del self._rx[: idx if idx > 0 else max(0, len(self._rx) - 1)]
        self._rx_event.set()

    def _on_stream(self, data: bytes) -> None:
        now = self.clock.now()
        if self.read_interval_s > 0 and self._transport is not None:
            self._transport.pause_reading()
            self._paused.set()
        batch = self._decoder.feed(data)
        self.counters["resync_bytes"] = self._decoder.resync_bytes
        a = self._assembler
        completed_before = a.completed
        revs = a.feed(batch)
        self._count_dropped()
        if a.completed > completed_before:  # kept or dropped, a new revolution has begun
            # Reads are batched: date the new revolution's start back by the nodes already
            # received of it, at the node rate of the revolution just completed.
            prev_start = self._rev_start
            node_s = 0.0
            if prev_start is not None:
                node_s = max(0.0, now - prev_start) / max(1, a.last_length + a.in_progress)
            new_start = now - a.in_progress * node_s
            for rev in revs:
                self._publish(rev, new_start)
            self._rev_start = new_start

    def _count_dropped(self) -> None:
        a = self._assembler
        self.counters["short_scans"] = a.short_scans
        self.counters["partial_scans"] = a.partial_scans

    def _publish(self, rev: p.NodeBatch, end: float) -> None:
        """Publish one revolution that ran from ``self._rev_start`` to ``end``."""
        now = self.clock.now()
        beams = self.cfg.beams
        ranges, intens = p.revolution_to_ranges(
            rev, beams, self.cfg.range_min_m, self.cfg.range_max_m, self.cfg.angle_offset_rad
        )
        start = self._rev_start if self._rev_start is not None else end - 0.1
        scan_time = max(1e-3, end - start)
        scan = LaserScan(
            stamp=start,
            angle_min_rad=-math.pi,
            angle_increment_rad=2 * math.pi / beams,
            range_min_m=self.cfg.range_min_m,
            range_max_m=self.cfg.range_max_m,
            ranges_m=ranges.astype(np.float32),
            intensities=intens.astype(np.float32),
            scan_time_s=scan_time,
            frame_id="laser",
        )
        self._last_scan_at = now
        self.counters["scans"] += 1
        self.bus.publish(SCAN, scan)
        self.reporter.recovered(now)

    # --- health -------------------------------------------------------------------------------
    def _report_down(self, exc: Exception) -> None:
        self.reporter.lost(str(exc), f"{exc} — the rover stays stopped until scans return")
