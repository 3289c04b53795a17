"""``operator-demo`` end to end on the simulator: the original's whole operator script."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import REPO_ROOT, load_config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


@pytest.mark.slow
async def test_operator_demo(tmp_path: Path) -> None:
    cfg = load_config(REPO_ROOT / "config.toml",
                      [f'data_dir="{tmp_path / "data"}"', "web.enabled=false"])
    report = await run_scenario(get_scenario("operator-demo"), cfg,
                                ScenarioArgs(seed=1, duration_s=400.0))
    assert report["success"], report["failure"]
    checks = {c["name"]: c["ok"] for c in report["checks"]}
    assert all(checks.values()) and len(checks) >= 18
    statuses = report["metrics"]["statuses"]
    expected = ["Moving to (0.2,0)", "Arrived at (0.2,0)", "Moving to (-0.2,0)",
                "Arrived at (-0.2,0)", "Moving to (0.5,0)", "Arrived at (0.5,0)",
                "Moving to (1,1)", "Arrived at (1,1)", "Moving to (2,2)", "Paused",
                "Moving to (2,2)", "Arrived at (2,2)", "Moving to (3,4)", "Going home",
                "Arrived at (0,0)", "Moving to (5,5.5)", "Arrived at (5,5.5)",
                "Moving to (1,11.6)", "Needs help", "Moving to (1,11.6)", "Arrived at (1,11.6)"]
    it = iter(statuses)
    assert all(any(s == want for s in it) for want in expected), statuses
    kinds = [e["kind"] for e in report["events"]]
    assert kinds.count("help.requested") == 1 and kinds.count("help.resolved") == 1
    assert kinds.index("help.requested") < kinds.index("help.resolved")
    accepted = [e["detail"]["action"] for e in report["events"]
                if e["kind"] == "bt.command_accepted"]
    assert accepted == ["select_path", "select_path", "pause", "resume", "go_home",
                        "select_path"]
    assert report["collisions"] == 0
    assert report["goals_reached"] == report["goals_total"] == 10
