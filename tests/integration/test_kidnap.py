"""The kidnap scenario end to end: the whole app on the simulator, teleported mid-tour."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import Config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


@pytest.mark.slow
async def test_kidnapped_rover_relocalises_and_the_report_has_the_figures(
        cfg: Config, tmp_path: Path) -> None:
    scenario = get_scenario("kidnap")
    scenario.kidnap_at_s = 12.0  # type: ignore[attr-defined]  # earlier than the CLI's 40 s
    report = await run_scenario(scenario, cfg, ScenarioArgs(seed=3, duration_s=26.0),
                                tmp_path / "report.json")
    assert report["success"], report["failure"]
    metrics = report["metrics"]
    assert metrics["lost_reported"] is True
    assert 0.0 < metrics["relocalization_time_s"] <= 15.0
    assert report["localization_rmse_m"] is not None
    kinds = [e["kind"] for e in report["events"]]
    assert "kidnap" in kinds and "relocalized" in kinds
    assert (tmp_path / "report.json").exists()


@pytest.mark.slow
async def test_a_rover_carried_away_while_parked_notices_and_relocalises(
        cfg: Config, tmp_path: Path) -> None:
    """No motion, so no filter update: the periodic check of the scan against the map must
    notice (before, the pose stayed ``ok`` at the old place for as long as it stood). Seed 1:
    seed 3 puts the rover at the default building's mirror image of home (13.5, 8.6, facing
    back), where the scan is the same as at home and no localiser can tell."""
    scenario = get_scenario("kidnap")
    scenario.kidnap_at_s = 8.0  # type: ignore[attr-defined]
    scenario.parked = True  # type: ignore[attr-defined]
    report = await run_scenario(scenario, cfg, ScenarioArgs(seed=1, duration_s=26.0),
                                tmp_path / "report.json")
    assert report["success"], report["failure"]
    assert report["metrics"]["lost_reported"] is True
    assert 0.0 < report["metrics"]["relocalization_time_s"] <= 15.0
