"""Issue 11's scenarios end to end on the whole simulated app: low battery and the dock, a
keep-out zone, the map that is wrong (lost and found). The report's metric names are
DESIGN.md's contract."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.scenarios import get_scenario
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, run_scenario

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


class _HomeThenElsewhere(Scenario):
    """Go Home with the dock, then an operator's goal on the way (the dashboard's goto)."""

    name = "home-then-elsewhere"
    description = "Go Home, replaced by a goal from the dashboard"
    default_duration_s = 40.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        bt = cfg.bt.model_copy(update={"tree": "tour", "speak": False, "tour_loop": False})
        dock = cfg.dock.model_copy(update={"enabled": True})
        sim = cfg.sim.model_copy(update={"start": (4.0, -2.0, 3.14)})
        return cfg.model_copy(update={"bt": bt, "dock": dock, "sim": sim})

    async def run(self, ctx: ScenarioContext) -> None:
        await ctx.sleep(1.0)
        ctx.press("go_home")
        await ctx.sleep(4.0)
        assert ctx.app.docker is not None and ctx.app.docker.state == "staging"
        goal = ctx.app.navigator.send_goal([Pose2D(6.0, -2.5, 0.0)], tag="web goto")
        ctx.check("the operator's goal reached",
                  await ctx.wait_until(lambda: goal.done, 30.0) and goal.state.value
                  == "succeeded", goal.state.value)
        ctx.check("docking stopped, not failed", ctx.app.docker.state == "idle",
                  ctx.app.docker.state)


async def test_a_goal_from_the_dashboard_replaces_docking_and_nobody_is_asked_for_help(
        cfg: Config) -> None:
    """The 24-hour soak with the dock (2026-12-02): an operator's goto while the rover drove
    to its dock made the docker fail ("could not reach the staging pose: preempted") and the
    tree ask for help ("I cannot reach my charger"). Now the docking stops, the goal drives."""
    report = await run_scenario(_HomeThenElsewhere(), cfg, ScenarioArgs(seed=1))
    assert report["success"], report["failure"]
    kinds = [e["kind"] for e in report["events"]]
    assert "dock.failed" not in kinds and "help.requested" not in kinds
