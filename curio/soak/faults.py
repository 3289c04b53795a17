"""Injecting each kind of fault into the running rover (child side), through the emulators'
and the simulator's own fault knobs, so the faults are real bytes, real timing and real files.

Each injector returns an :class:`Injection`: which parts' ``/health`` must show the fault,
which event-log records prove it was logged, how long the judge waits for the rover to
recover, and (for faults that last) a coroutine that ends the fault condition. The judge
(:mod:`curio.soak.judge`) does the rest.

=================  ===================================================================
kind               what is done
=================  ===================================================================
lidar_unplug       ``RplidarEmulator.unplug()``; ``replug()`` after ``down_s``
lidar_garbage      ``RplidarEmulator.inject_garbage(bytes)``, ``bursts`` times 0.3 s apart
arduino_reset      ``ArduinoEmulator.reset()`` while the rover drives (the wheels stop,
                   bootloader window, BOOT)
crc_burst          ``corrupt_tx(tx_frames)`` (CRC errors to the host) and ``corrupt_rx(rx_s)``
                   (frames from the host corrupted) while driving
i2c_errors         the BNO055 bus fails ``rate`` of its transactions for ``duration_s``
imu_stuck          the BNO055's output registers freeze until it is re-initialised
loop_stall         the event loop is blocked for ``stall_s`` (``SimClock.block``): nothing in
                   the application runs meanwhile, while the world and the Arduino's own
                   firmware (its watchdog) go on
disk_full          a ballast file fills the data directory's filesystem (a size-limited
                   tmpfs), removed after ``duration_s``
kidnap             ``World.teleport`` to a free pose at least 3 m away while driving
kidnap_parked      the same while the rover stands still (no odometry motion to update on)
kill9, corrupt     the orchestrator kills the process (``SIGKILL``); ``corrupt_file`` then
_file              damages tours, paths or schedules before the restart
=================  ===================================================================
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from curio.core.geometry import Pose2D
from curio.drivers.arduino.protocol import McuState
from curio.soak.plan import KIDNAP_KINDS, PlannedFault

__all__ = ["DEADLINES_S", "Injection", "Targets", "fill_disk", "inject"]

# How long the judge waits for the rover to recover after the fault condition ended, seconds.
DEADLINES_S = {
    "lidar_unplug": 20.0, "lidar_garbage": 20.0, "arduino_reset": 20.0, "crc_burst": 20.0,
    "i2c_errors": 25.0, "imu_stuck": 25.0, "loop_stall": 25.0, "disk_full": 40.0,
    "kidnap": 60.0, "kidnap_parked": 60.0, "kill9": 120.0, "corrupt_file": 120.0,
}
BALLAST_CHUNK = 1 << 20
DISK_WALL_DEADLINE_S = 20.0  # wall seconds for the writer threads' retries after a full disk


@dataclass
class Targets:
    """What the injectors act on (emulators by role, the world, the clock, the ballast)."""

    app: Any
    clock: Any
    lidar: Any = None
    arduino: Any = None
    imu: Any = None
    ballast: Path | None = None

    @classmethod
    def of(cls, app: Any, clock: Any, ballast: Path | None) -> Targets:
        """The targets of ``app``'s emulators (found by type)."""
        from curio.drivers.arduino.emulator import ArduinoEmulator
        from curio.drivers.bno055.emulator import Bno055Emulator
        from curio.drivers.rplidar.emulator import RplidarEmulator

        out = cls(app, clock, ballast=ballast)
        for emu in app.emulators:
            if isinstance(emu, RplidarEmulator):
                out.lidar = emu
            elif isinstance(emu, ArduinoEmulator):
                out.arduino = emu
            elif isinstance(emu, Bno055Emulator):
                out.imu = emu
        return out


@dataclass
class Injection:
    """What an injector did and how it is judged.

    Attributes:
        health: parts whose ``/health`` must leave ``ok`` (any one of them counts).
        log_kinds: event-log kinds that prove it was logged (besides ``fault`` records of the
            ``health`` parts).
        clear: a coroutine that ends the fault condition (None: it was instantaneous).
        deadline_s: how long after the condition ended the rover may take to recover.
        recovered: extra condition for recovery beyond every recovery part being ``ok``.
        note: what was done, for the report.
        recovery_parts: the parts that must be ``ok`` again (default: ``health``).
        wall_deadline_s: for parts that retry on the wall clock (the recorder's and the event
            log's writer threads after a full disk: every 5 s and 2 s of wall time), the
            deadline is also at least this many wall seconds after the condition ended — the
            soak's simulated clock runs 15–70× faster than those retries.
    """

    health: tuple[str, ...]
    log_kinds: tuple[str, ...] = ()
    clear: Callable[[], Awaitable[None]] | None = None
    deadline_s: float = 20.0
    recovered: Callable[[], bool] | None = None
    note: dict[str, Any] = field(default_factory=dict)
    recovery_parts: tuple[str, ...] | None = None
    wall_deadline_s: float | None = None

    @property
    def must_recover(self) -> tuple[str, ...]:
        """The parts that must report ``ok`` again."""
        return self.health if self.recovery_parts is None else self.recovery_parts


def fill_disk(ballast: Path) -> int:
    """Write zeros to ``ballast`` until its filesystem is full; return the bytes written."""
    written = 0
    chunk = bytes(BALLAST_CHUNK)
    fd = os.open(ballast, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    try:
        size = len(chunk)
        while size >= 512:
            try:
                written += os.write(fd, chunk[:size])
            except OSError as exc:
                if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                    raise
                size //= 2
    finally:
        os.close(fd)
    return written


def _kidnap_target(world: Any, seed: int) -> Pose2D:
    from curio.estimation.localization import DistanceField

    rng = np.random.default_rng(seed)
    grid = world.grid
    dist = DistanceField(grid, 2.0)
    rows, cols = np.nonzero(grid.free_mask() & (dist.dist_m >= 0.6))
    here = world.truth_pose
    for _ in range(5000):
        i = int(rng.integers(len(rows)))
        x, y = grid.cell_to_world(int(rows[i]), int(cols[i]))
        pose = Pose2D(x, y, float(rng.uniform(-math.pi, math.pi)))
        if pose.distance_to(here) >= 3.0 and not world.collides(pose):
            return pose
    raise RuntimeError("no free pose for the kidnap")


async def _stall(t: Targets, seconds: float) -> None:
    """Block the loop for ``seconds`` of simulated time: the world and the Arduino's firmware
    (its own microcontroller) go on in steps of one physics period; the application does not."""
    world, emu, clock = t.app.world, t.arduino, t.clock
    dt = 1.0 / t.app.cfg.sim.physics_rate_hz
    for _ in range(max(1, round(seconds / dt))):
        clock.block(dt)
        if emu is not None and emu.state != McuState.BOOT:
            emu.firmware.tick(int(clock.now() * 1000.0) & 0xFFFFFFFF)
        world.step(dt)


def inject(fault: PlannedFault, t: Targets) -> Injection:
    """Inject ``fault`` now; see the module docstring for each kind."""
    kind, p = fault.kind, fault.params
    deadline = DEADLINES_S.get(kind, 20.0)
    if kind == "lidar_unplug":
        t.lidar.unplug()

        async def replug() -> None:
            await t.clock.sleep(float(p["down_s"]))
            t.lidar.replug()

        return Injection(("lidar",), ("driver.lidar_lost",), replug, deadline)
    if kind == "lidar_garbage":
        async def bursts() -> None:
            for i in range(int(p["bursts"])):
                if i:
                    await t.clock.sleep(0.3)
                t.lidar.inject_garbage(int(p["bytes"]))

        return Injection(("lidar",), (), bursts, deadline)
    if kind == "arduino_reset":
        t.arduino.reset()
        return Injection(("arduino",), (), None, deadline)
    if kind == "crc_burst":
        t.arduino.corrupt_tx(int(p["tx_frames"]))
        t.arduino.corrupt_rx(float(p["rx_s"]))

        async def burst_over() -> None:
            await t.clock.sleep(float(p["rx_s"]))

        return Injection(("arduino",), (), burst_over, deadline)
    return _inject_more(fault, t, deadline)


def _inject_more(fault: PlannedFault, t: Targets, deadline: float) -> Injection:
    kind, p = fault.kind, fault.params
    if kind == "i2c_errors":
        t.imu.faults.io_error_rate = float(p["rate"])

        async def calm() -> None:
            await t.clock.sleep(float(p["duration_s"]))
            t.imu.faults.io_error_rate = 0.0

        return Injection(("imu",), (), calm, deadline)
    if kind == "imu_stuck":
        t.imu.faults.frozen = True
        return Injection(("imu",), (), None, deadline)
    if kind == "loop_stall":
        stall_s = float(p.get("stall_s", 2.0))

        async def stall() -> None:
            await _stall(t, stall_s)

        return Injection(("loop",), ("loop.stalled",), stall, deadline,
                         recovery_parts=("loop", "lidar", "arduino", "imu"))
    if kind == "disk_full":
        if t.ballast is None:
            raise RuntimeError("disk_full needs a size-limited data filesystem")
        written = fill_disk(t.ballast)
        ballast = t.ballast

        async def free() -> None:
            await t.clock.sleep(float(p["duration_s"]))
            with contextlib.suppress(FileNotFoundError):
                ballast.unlink()

        return Injection(("recorder", "eventlog"), (), free, deadline,
                         note={"ballast_mb": round(written / 1e6, 1)},
                         wall_deadline_s=DISK_WALL_DEADLINE_S)
    if kind in KIDNAP_KINDS:
        target = _kidnap_target(t.app.world, int(p["seed"]))
        before = t.app.world.truth_pose
        t.app.world.teleport(target)
        return Injection(("localization",), ("localization.lost",), None, deadline,
                         note={"from": [round(before.x, 2), round(before.y, 2)],
                               "to": [round(target.x, 2), round(target.y, 2)]})
    raise ValueError(f"no injector for fault kind {kind!r}")
