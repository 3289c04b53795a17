"""Proof that the RPLidar emulator speaks the real protocol: a client library not written for
Curio (``rplidar-roboticia``) reads scans from it over a pseudo-terminal.

A pty cannot carry the DTR line that switches the A1's motor, so pyserial's DTR call (which
fails with ENOTTY on a pty) is routed to the emulator's motor hook: the library's own
``start_motor`` then really starts the emulated motor.
"""

from __future__ import annotations

import asyncio
import math
from typing import Any

import numpy as np
import pytest
import rplidar  # rplidar-roboticia, in the `test` extra
import serial.serialposix

from curio.core.clock import RealClock
from curio.core.messages import LaserScan
from curio.drivers.rplidar.emulator import RplidarEmulator


def wall_ranges(angles_rad: np.ndarray) -> np.ndarray:
    """A scene: 2 m + 0.5 m·sin(angle), so every direction has its own range."""
    return 2.0 + 0.5 * np.sin(angles_rad)


def scan_source(stamp: float) -> LaserScan:
    n = 360
    angles = -math.pi + np.arange(n) * (2 * math.pi / n)
    ranges = wall_ranges(angles).astype(np.float32)
    ranges[10] = np.inf  # one beam without return: distance 0, filtered by the client
    return LaserScan(stamp, -math.pi, 2 * math.pi / n, 0.15, 12.0, ranges)


@pytest.mark.timeout(30)
async def test_rplidar_roboticia_reads_scans_from_emulator(monkeypatch: Any) -> None:
    loop = asyncio.get_running_loop()
    emu = RplidarEmulator(scan_source, RealClock(), rate_hz=10.0, spin_up_s=0.1,
                          motor_on=False)
    emu.open()
    server = asyncio.create_task(emu.run())

    def dtr_to_motor(self: serial.serialposix.Serial) -> None:
        # DTR cleared = motor spins (A1 MOTOCTL).
        loop.call_soon_threadsafe(emu.set_motor, not self._dtr_state)

    monkeypatch.setattr(serial.serialposix.Serial, "_update_dtr_state", dtr_to_motor)

    def client() -> tuple[dict[str, Any], tuple[str, int], list[list[tuple[float, float, float]]]]:
        lidar = rplidar.RPLidar(emu.path, baudrate=115200, timeout=2)
        try:
            info = lidar.get_info()
            health = lidar.get_health()
            scans = []
            for scan in lidar.iter_scans():
                scans.append(scan)
                if len(scans) == 4:
                    break
            lidar.stop()
            lidar.stop_motor()
            return info, health, scans
        finally:
            lidar.disconnect()

    try:
        info, health, scans = await asyncio.to_thread(client)
    finally:
        server.cancel()
        await emu.close()
    assert info["model"] == 0x18
    assert info["firmware"] == (1, 29)
    assert info["hardware"] == 7
    assert health == ("Good", 0)
    assert not emu.motor_on  # the library's stop_motor reached the emulated motor
    assert emu.requests.count(0x20) >= 1  # SCAN
    for scan in scans[1:]:  # the first one may be partial
        assert 340 <= len(scan) <= 359  # one beam had no return
        _, angle_deg, dist_mm = (np.array(c) for c in zip(*scan, strict=True))
        assert np.all(np.diff(angle_deg) > 0)  # clockwise, one revolution
        laser = math.pi - np.radians(angle_deg)  # rplidar_ros: laser = pi - raw
        np.testing.assert_allclose(dist_mm / 1000.0, wall_ranges(laser), atol=0.003)


@pytest.mark.timeout(60)
def test_rplidar_roboticia_reads_curio_emulate(tmp_path: Any, monkeypatch: Any) -> None:
    """The done-criterion as a user runs it: `curio emulate rplidar` in its own process, the
    unmodified client on the printed path (the emulated motor is always on; the library's DTR
    calls, which a pty refuses with ENOTTY, are made no-ops)."""
    import subprocess
    import sys

    monkeypatch.setattr(serial.serialposix.Serial, "_update_dtr_state", lambda self: None)
    link = tmp_path / "lidar"
    proc = subprocess.Popen(
        [sys.executable, "-m", "curio", "emulate", "rplidar", "--link", str(link),
         "--duration", "30", "--set", "sim.lidar_rate_hz=10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert "emulator on" in first, first + (proc.stderr.read() if proc.stderr else "")
        path = first.strip().rsplit(" ", 1)[-1]
        assert path == str(link)
        lidar = rplidar.RPLidar(path, baudrate=115200, timeout=2)
        try:
            assert lidar.get_info()["model"] == 0x18
            scans = []
            for scan in lidar.iter_scans():
                scans.append(scan)
                if len(scans) == 3:
                    break
            lidar.stop()
        finally:
            lidar.disconnect()
        for scan in scans[1:]:
            # The shipped world seen from the rover's start: most beams hit a wall.
            assert len(scan) >= 250
            dist_m = np.array([m[2] for m in scan]) / 1000.0
            assert dist_m.min() >= 0.15 and dist_m.max() <= 12.0
    finally:
        proc.terminate()
        proc.wait(10)
