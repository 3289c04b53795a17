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
