"""The ``square`` scenario end to end on the whole application (simulated time)."""

from __future__ import annotations

from pathlib import Path

from curio.core.config import Config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


async def test_square_report_and_determinism(cfg: Config, tmp_path: Path) -> None:
    first = await run_scenario(get_scenario("square"), cfg, ScenarioArgs(seed=1),
                               report_path=tmp_path / "r.json")
    assert first["success"], first["failure"]
    assert (tmp_path / "r.json").is_file()
    m = first["metrics"]
    assert first["collisions"] == 0
    # The rover really drove about 8 m, and odometry stayed within the stated bounds.
    assert 7.5 < first["path_length_m"] < 9.5
    assert 0.0 < m["wheel_odom_final_error_m"] <= m["bound_position_m"]
    assert abs(m["wheel_odom_final_heading_error_rad"]) <= m["bound_heading_rad"]
    assert len(m["wheel_odom_side_errors_m"]) == 4
    assert [e["detail"]["side"] for e in first["events"] if e["kind"] == "square.side"] == [
        1, 2, 3, 4]
    second = await run_scenario(get_scenario("square"), cfg, ScenarioArgs(seed=1))
    first.pop("wall_time_s")
    second.pop("wall_time_s")
    assert first == second


async def test_square_without_noise_is_accurate(cfg: Config) -> None:
    cfg.sim.noise.odom_scale_error = 0.0
    cfg.sim.noise.odom_heading_drift_rad_per_m = 0.0
    report = await run_scenario(get_scenario("square"), cfg, ScenarioArgs(seed=1))
    assert report["success"], report["failure"]
    # What remains is the scrub while the corner servos swing: a few cm over 8 m.
    assert report["metrics"]["wheel_odom_final_error_m"] < 0.2
