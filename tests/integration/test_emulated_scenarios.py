"""The README's claim that every scenario also runs with ``drivers.mode = "emulated"`` (the
real Arduino, RPLidar and BNO055 drivers against byte-exact emulators on pseudo-terminals and
a fake I2C bus), for ``tour``, ``operator-demo`` and ``blocked-door`` (a short tour)."""

from __future__ import annotations

import math

import pytest

from curio.core.config import Config, TourStopConfig
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def emulated(cfg: Config) -> Config:
    drivers = cfg.drivers.model_copy(update={"mode": "emulated"})
    return cfg.model_copy(update={"drivers": drivers})


async def test_tour_emulated(cfg: Config) -> None:
    report = await run_scenario(get_scenario("tour"), emulated(cfg), ScenarioArgs(seed=1))
    assert report["drivers_mode"] == "emulated"
    assert report["success"], report["failure"]
    assert report["goals_reached"] == report["goals_total"] == 7


async def test_operator_demo_emulated(cfg: Config) -> None:
    report = await run_scenario(get_scenario("operator-demo"), emulated(cfg),
                                ScenarioArgs(seed=1))
    assert report["drivers_mode"] == "emulated"
    assert report["success"], (report["failure"], report["checks"])
    assert report["collisions"] == 0


async def test_blocked_door_emulated(cfg: Config) -> None:
    stops = [TourStopConfig(name="Corridor", x_m=8.0, y_m=8.3, dwell_s=1.0, message="c"),
             TourStopConfig(name="Library", x_m=1.0, y_m=11.8, dwell_s=1.0, message="l")]
    cfg = emulated(cfg.model_copy(update={"bt": cfg.bt.model_copy(update={
        "tour_stops": stops})}))
    report = await run_scenario(get_scenario("blocked-door"), cfg, ScenarioArgs(
        seed=1, duration_s=400.0, start=(12.0, 8.3, math.pi)))
    assert report["drivers_mode"] == "emulated"
    assert report["success"], (report["failure"], report["checks"])
    events = report["events"]
    opened = next(e["t"] for e in events if e["kind"] == "door" and e["detail"]["open"])
    thanks = next(e["t"] for e in events if e["kind"] == "help.resolved")
    assert 0.0 <= thanks - opened <= 3.0
