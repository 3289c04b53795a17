"""Issue 11's scenarios end to end on the whole simulated app: low battery and the dock, a
keep-out zone, the map that is wrong (lost and found). The report's metric names are
DESIGN.md's contract."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import Config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


async def test_low_battery_docks_charges_and_runs_the_next_tour(cfg: Config) -> None:
    report = await run_scenario(get_scenario("low-battery"), cfg, ScenarioArgs(seed=1))
    assert report["success"], (report["failure"], report["checks"])
    m = report["metrics"]
    assert {"dock_attempts", "dock_successes", "dock_error_m", "dock_error_deg",
            "min_battery_v"} <= set(m)
    assert m["dock_successes"] == 2 and m["dock_attempts"] >= 2
    assert m["dock_error_m"] <= 0.02 and m["dock_error_deg"] <= 2.0
    assert 6.3 <= m["min_battery_v"] < 6.6  # low, never critical
    kinds = [e["kind"] for e in report["events"]]
    assert kinds.index("battery.low") < kinds.index("tour.stopped") < kinds.index(
        "dock.docked") < kinds.index("battery.ok") < kinds.index("tour.finished")
    assert report["collisions"] == 0


async def test_keepout_zone_is_never_entered_and_speed_zone_respected(cfg: Config) -> None:
    report = await run_scenario(get_scenario("keepout"), cfg, ScenarioArgs(seed=2))
    assert report["success"], (report["failure"], report["checks"])
    m = report["metrics"]
    assert m["zone_violations"] == 0 and m["speed_zone_violations"] == 0
    assert m["cycles_in_speed_zone"] > 100  # it really drove through the speed zone
    assert 0.0 < m["min_keepout_clearance_m"] < 0.5  # and came close to the keep-out zone
    assert report["path_length_m"] > 2 * m["straight_m"]


async def test_lost_when_the_map_is_wrong_then_found_and_the_tour_finishes(cfg: Config,
                                                                          tmp_path: Path
                                                                          ) -> None:
    report = await run_scenario(get_scenario("lost"), cfg, ScenarioArgs(seed=1),
                                tmp_path / "lost.json")
    assert report["success"], (report["failure"], report["checks"])
    m = report["metrics"]
    assert m["lost_episodes"] >= 1 and m["moved_while_lost_m"] < 0.15
    kinds = [e["kind"] for e in report["events"]]
    assert kinds.count("localization.lost") == kinds.count("localization.found")
    assert "tour.finished" in kinds and report["collisions"] == 0
