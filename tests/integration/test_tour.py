"""``tour`` end to end on the default building: paths 1 and 2, then home."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import REPO_ROOT, load_config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


@pytest.mark.slow
async def test_tour_reaches_every_waypoint(tmp_path: Path) -> None:
    cfg = load_config(REPO_ROOT / "config.toml",
                      [f'data_dir="{tmp_path / "data"}"', "web.enabled=false"])
    report = await run_scenario(get_scenario("tour"), cfg, ScenarioArgs(seed=1,
                                                                        duration_s=300.0))
    assert report["success"], report["failure"]
    n = sum(len(cfg.bt.paths[i].points) for i in (1, 2, 0))
    assert report["goals_total"] == n and report["goals_reached"] == n
    assert report["collisions"] == 0
    wps = report["metrics"]["waypoints"]
    assert [w["path"] for w in wps] == [1] * 3 + [2] * 3 + [0]
    assert all(w["state"] == "succeeded" for w in wps)
