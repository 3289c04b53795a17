"""The ``drivers.mode`` table: one row per mode, and the wiring follows it device by device."""

from __future__ import annotations

from typing import get_args

import pytest

from curio.core.clock import SimClock
from curio.core.config import DriversConfig, load_config
from curio.core.parts import Parts
from curio.core.topics import make_bus
from curio.drivers import modes
from curio.drivers.modes import MODES, DriverMode
from curio.drivers.wiring import build_drivers
from curio.robot import RobotModel
from curio.sim.wiring import build_sim


def test_every_configurable_mode_has_a_row() -> None:
    assert set(MODES) == set(get_args(DriversConfig.model_fields["mode"].annotation))


def test_rows() -> None:
    sim, emulated, real = MODES["sim"], MODES["emulated"], MODES["real"]
    assert sim.world and sim.simulated and not sim.emulated
    assert emulated.world and emulated.emulated and not emulated.simulated
    assert not real.world and not real.emulated and not real.simulated
    assert emulated.source("lidar") == "emulator" and real.source("imu") == "hardware"


async def _part_names(monkeypatch: pytest.MonkeyPatch, row: DriverMode) -> list[str]:
    monkeypatch.setitem(modes.MODES, "sim", row)
    cfg = load_config(None, [])
    bus, clock, parts = make_bus(), SimClock(), Parts()
    robot = RobotModel.from_config(cfg.robot)
    sim = build_sim(cfg, bus, clock, parts, robot)
    assert sim is not None
    drivers = build_drivers(cfg, bus, clock, parts, robot, world=sim.world, sim_base=sim.base)
    for emulator in drivers.emulators:
        for part in emulator.parts():
            if part.close is not None:
                await part.close()  # removes its temporary directory
    return [part.name for part in parts.parts]


async def test_the_wiring_follows_the_table_per_device(monkeypatch: pytest.MonkeyPatch) -> None:
    assert await _part_names(monkeypatch, MODES["sim"]) == [
        "sim.physics", "sim.battery", "sim.base", "sim.base.watchdog", "sim.lidar", "sim.imu",
        "sim.wheels", "odometry"]
    # An emulated base with a simulated lidar and IMU: each device follows its own cell.
    mixed = DriverMode("sim", base="emulator", lidar="simulator", imu="simulator")
    assert await _part_names(monkeypatch, mixed) == [
        "sim.physics", "sim.battery", "sim.lidar", "sim.imu", "odometry", "arduino-emulator",
        "arduino"]
