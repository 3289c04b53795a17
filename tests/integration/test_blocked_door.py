"""``blocked-door`` end to end: a door closes in front of the touring rover and reopens;
"Thanks!" comes within 3 s of the opening, never while the door is closed.

A short tour (two stops, the second behind the library door, the only way in) keeps it fast;
``curio sim blocked-door`` runs the building's whole tour.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from curio.core.config import REPO_ROOT, TourStopConfig, load_config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


@pytest.mark.slow
async def test_blocked_door(tmp_path: Path) -> None:
    cfg = load_config(REPO_ROOT / "config.toml",
                      [f'data_dir="{tmp_path / "data"}"', "web.enabled=false"])
    stops = [TourStopConfig(name="Corridor", x_m=8.0, y_m=8.3, dwell_s=1.0,
                            message="This corridor joins every room."),
             TourStopConfig(name="Library", x_m=1.0, y_m=11.8, dwell_s=1.0,
                            message="The library.")]
    cfg = cfg.model_copy(update={"bt": cfg.bt.model_copy(update={"tour_stops": stops})})
    report = await run_scenario(get_scenario("blocked-door"), cfg,
                                ScenarioArgs(seed=1, duration_s=400.0,
                                             start=(12.0, 8.3, math.pi)))
    assert report["success"], report["failure"]
    events = report["events"]
    kinds = [e["kind"] for e in events]
    closed = next(e["t"] for e in events if e["kind"] == "door" and not e["detail"]["open"])
    opened = next(e["t"] for e in events if e["kind"] == "door" and e["detail"]["open"])
    requested = next(e for e in events if e["kind"] == "help.requested")
    resolved = next(e for e in events if e["kind"] == "help.resolved")
    assert closed <= requested["t"] < opened <= resolved["t"]
    assert resolved["detail"]["message"] == "Thanks!"
    # Issue 11: "Thanks!" from fresh lidar evidence, within 3 s of the door opening, and
    # never while it is closed (one resolution, after the opening: above).
    assert resolved["t"] - opened <= 3.0, resolved["t"] - opened
    assert kinds.count("help.resolved") == 1
    assert kinds.count("help.requested") == 1
    stops_seen = [e["detail"]["name"] for e in events if e["kind"] == "tour.stop"]
    assert stops_seen == ["Corridor", "Library"]
    assert report["collisions"] == 0 and report["goals_reached"] == 2
