"""``curio sim crowd`` end to end: among visitors, deterministic, with the crowd metrics."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from curio.core.config import REPO_ROOT, load_config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

METRICS = ("collisions_rover_at_fault", "collisions_person_at_fault", "min_person_distance_m",
           "time_below_0_3m_s", "tracks_mota")


async def _goto(tmp_path: Path, seed: int, *extra: str) -> dict[str, Any]:
    cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path / "data"}"', "web.enabled=false", "bt.speak=false", *extra])
    args = ScenarioArgs(start=(0.0, 0.0, 0.0), goal=(5.0, 3.0, None), seed=seed, visitors=8,
                        duration_s=150.0)
    return await run_scenario(get_scenario("crowd"), cfg, args)


@pytest.mark.slow
async def test_same_seed_same_report(tmp_path: Path) -> None:
    """Among eight visitors, a goal in the lobby: the same seed gives the same report
    (wall time aside), the report has the crowd metrics, and the rover gets there."""
    a = await _goto(tmp_path, 4)
    b = await _goto(tmp_path, 4)
    for r in (a, b):
        r.pop("wall_time_s")
    assert a == b
    assert a["success"], a["failure"]
    m = a["metrics"]
    assert all(key in m for key in METRICS)
    assert m["visitors"] == 8 and m["controller"] == "aware" and m["mode"] == "goto"
    assert m["collisions_rover_at_fault"] == 0
    assert m["tracks_mota"] is not None and m["tracks_mota"] > 0.8
    c = await _goto(tmp_path, 5)
    assert c["events"] != a["events"]  # another seed, another crowd


async def test_an_open_field_full_of_visitors_is_not_a_lost_rover(
        tmp_path: Path, shared_maps: Path) -> None:
    """``curio_shapes`` is an open field with a few shapes and no walls round it: near its
    rim most lidar returns among ten visitors are legs. The localiser drops the returns on
    tracked people, so it neither declares itself lost at the right pose (it did within 5 s,
    and its search then put the rover outside the map) nor cancels the goal; the benchmark's
    job (``bench crowd --pairs 200 --seed 1``, seed 100117) reaches its goal."""
    world = shared_maps / "curio_shapes" / "shapes_footprint.yaml"
    cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path / "data"}"', "web.enabled=false", "bt.speak=false",
        f'sim.world="{world}"'])
    args = ScenarioArgs(start=(4.625, -7.975, -0.1776), goal=(4.175, 4.375, None),
                        seed=100117, visitors=10, duration_s=160.0)
    report = await run_scenario(get_scenario("crowd"), cfg, args)
    assert report["success"], report["failure"]
    kinds = [e["kind"] for e in report["events"]]
    assert "localization.lost" not in kinds and "localization.jump" not in kinds
    assert report["metrics"]["localization_max_error_m"] < 0.2
