"""The whole application in ``drivers.mode = "emulated"``: the real Arduino, RPLidar and BNO055
drivers talk over pseudo-terminals and the fake I2C bus to the emulators fed by the simulator.

Checks that the sensor streams arrive through the drivers, that the lidar's frame matches the
simulator's (``laser``, counter-clockwise from -pi), that teleop moves the simulated rover
through the Arduino link, and that pulling the lidar's cable stops the rover (the safety stage
holds it still without scans) until the driver has recovered by itself.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import load_config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, CMD_VEL_TELEOP, EVENTS, HEALTH, IMU, SCAN, WHEELS

pytestmark = [pytest.mark.timeout(120), pytest.mark.slow]


@pytest.fixture
async def app(tmp_path: Path) -> AsyncIterator[App]:
    cfg = load_config(None, [f'data_dir="{tmp_path}"', "web.enabled=false",
                             'drivers.mode="emulated"'])
    clock = SimClock(settle_polls=3)
    application = App(cfg, clock, web=False)
    await application.start()
    yield application
    await application.stop()


async def run_until(app: App, t_s: float) -> None:
    clock = app.clock
    assert isinstance(clock, SimClock)
    await clock.run(until_s=t_s)
    assert not app.failed_parts(), app.failed_parts()


async def test_emulated_drivers_stream_and_drive(app: App) -> None:
    bus = app.bus
    assert app.lidar is not None and app.imu is not None and app.base is not None
    assert len(app.emulators) == 3
    scans = bus.subscribe(SCAN, maxsize=1000)
    imus = bus.subscribe(IMU, maxsize=10000)
    wheels = bus.subscribe(WHEELS, maxsize=10000)
    events = bus.subscribe(EVENTS)
    health = bus.subscribe(HEALTH, maxsize=1000)
    cmd = bus.subscribe(CMD_VEL, maxsize=10000)

    await run_until(app, 4.0)
    n_scans, n_imu, n_wheels = len(scans.drain()), len(imus.drain()), len(wheels.drain())
    # Lidar at 10 Hz, IMU at 100 Hz, wheel feedback at 30 Hz, each after its start-up.
    assert n_scans >= 25, app.lidar.message
    assert n_imu >= 250, app.imu.message
    assert n_wheels >= 60
    assert app.lidar.state == "ok" and app.imu.state == "ok"

    # The driver's scan shows the world as the simulator casts it (same frame and angles).
    await run_until(app, 4.35)
    scan = bus.latest(SCAN)
    assert scan is not None and scan.frame_id == "laser"
    truth = app.world.cast_scan(app.clock.now())
    both = np.isfinite(scan.ranges_m) & np.isfinite(truth.ranges_m)
    assert both.sum() > 200
    close = np.abs(scan.ranges_m[both] - truth.ranges_m[both]) < 0.1
    assert close.mean() > 0.9

    # Teleop drives the simulated rover through the real Arduino driver and the emulator.
    start = app.world.truth_pose

    async def teleop(until_s: float) -> None:
        while app.clock.now() < until_s:
            bus.publish(CMD_VEL_TELEOP, Twist(app.clock.now(), 0.0, 0.4, source="teleop"))
            await app.clock.sleep(0.1)

    task = asyncio.create_task(teleop(9.0))
    await run_until(app, 6.0)
    turned = app.world.truth_pose.yaw - start.yaw
    assert abs(math.remainder(turned, 2 * math.pi)) > 0.3  # it turns in place

    # Pull the lidar's cable: no scans, the safety stage stops the rover, health says why.
    lidar_emu = app.emulators[1]
    lidar_emu.unplug()
    await run_until(app, 8.0)
    cmd.drain()
    health.drain()
    yaw_before = app.world.truth_pose.yaw
    await run_until(app, 9.0)
    assert all(abs(c.angular_radps) < 1e-6 and abs(c.linear_mps) < 1e-6 for c in cmd.drain())
    assert abs(app.world.truth_pose.yaw - yaw_before) < 0.02
    assert app.lidar.state == "error"
    assert any(h.name == "lidar" and h.state == "error" for h in health.drain())
    task.cancel()

    # Plug it back: the driver recovers by itself and teleop moves the rover again.
    lidar_emu.replug()
    task = asyncio.create_task(teleop(14.0))
    await run_until(app, 14.0)
    assert app.lidar.state == "ok"
    kinds = [e.kind for e in events.drain()]
    assert "driver.lidar_lost" in kinds and "driver.lidar_recovered" in kinds
    assert abs(app.world.truth_pose.yaw - yaw_before) > 0.3
    task.cancel()
