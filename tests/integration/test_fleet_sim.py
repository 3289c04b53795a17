"""The fleet simulator: two rovers through the narrowest doorway, and a rover that loses its
link in the middle of a tour (each rover its own application; Zenoh sessions over the
loopback). The 50-seed doorway run is a benchmark: ``curio bench fleet``."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import Config
from curio.scenarios.fleet import get_fleet_scenario
from curio.scenarios.fleet.base import FleetArgs, run_fleet


def _quiet(report: dict) -> dict:
    return {k: v for k, v in report.items() if k not in ("wall_time_s", "transport")}


@pytest.mark.slow
async def test_two_rovers_pass_the_workshop_doorway_without_collision_or_deadlock(
        cfg: Config) -> None:
    pytest.importorskip("zenoh")
    scenario = get_fleet_scenario("doorway")
    # Seed 5: they meet head on and one of them gives way.
    zen = await run_fleet(scenario, cfg, FleetArgs(seed=5, transport="zenoh"))
    assert zen["success"], zen["failure"]
    m = zen["metrics"]
    assert m["rover_rover_collisions"] == 0 and m["rover_rover_encounters"] >= 1
    # The one that gives way slows on its way to its staging point and goes once the other is
    # through; any stop there within issue 17's 10 s (none on this seed since the slow
    # approach: it was 7.5 s before; the 50 seeds of `curio bench fleet` are in docs/fleet.md).
    assert m["longest_standoff_s"] <= 10.0
    assert m["delivery_timeouts"] == 0
    kinds = [(e["rover"], e["kind"]) for e in zen["events"] if e["kind"].startswith("traffic")]
    yielded = {r for r, k in kinds if k == "traffic.yield"}
    assert len(yielded) == 1 and (yielded.pop(), "traffic.resume") in kinds, kinds
    # The same run over the in-process transport: the very same day (reproducible).
    mem = await run_fleet(scenario, cfg, FleetArgs(seed=5, transport="memory"))
    zen["metrics"].pop("delivery_timeouts")
    assert _quiet(mem) == _quiet(zen)


@pytest.mark.slow
async def test_a_rover_that_loses_its_link_mid_tour_carries_on_and_its_tour_moves(
        cfg: Config, tmp_path: Path) -> None:
    pytest.importorskip("zenoh")
    report = await run_fleet(get_fleet_scenario("disconnect"), cfg,
                             FleetArgs(seed=1, transport="zenoh"), tmp_path / "r.json")
    checks = {c["name"]: c for c in report["checks"]}
    assert report["success"], [c for c in report["checks"] if not c["ok"]]
    assert checks["the manager chose the rover nearer the first stop"]["ok"]
    assert checks["r1 kept guiding after the cut"]["ok"]
    assert checks["the tour was re-dispatched to r2 and finished there"]["ok"]
    assert report["collisions"] == 0
    assert report["metrics"]["redispatched_after_s"] >= 20.0
    assert report["metrics"]["delivery_timeouts"] == 0
    assert (tmp_path / "r.json").is_file()
