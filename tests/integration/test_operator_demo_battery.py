"""The tour guide on the whole simulated app: the servo supply sags during a tour, the rover
goes home once (hysteresis), refuses a new tour until the battery recovers, then tours again."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.core.config import REPO_ROOT, Config, TourStopConfig, load_config
from curio.core.messages import Event
from curio.core.topics import EVENTS
from curio.scenarios.base import (
    Scenario,
    ScenarioArgs,
    ScenarioContext,
    ScenarioFailed,
    run_scenario,
)


class LowBatteryTour(Scenario):
    name = "low-battery-tour"
    default_duration_s = 300.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        stops = [TourStopConfig(name="Desk", x_m=2.0, y_m=-2.5, dwell_s=1.0, message="Hi."),
                 TourStopConfig(name="Pillar", x_m=5.0, y_m=3.0, dwell_s=1.0, message="Bye.")]
        bt = cfg.bt.model_copy(update={"tree": "tour", "tour_stops": stops, "speak": False})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: ScenarioContext) -> None:
        sub = ctx.bus.subscribe(EVENTS)
        seen: list[Event] = []

        def of(kind: str) -> list[Event]:
            seen.extend(sub.drain())
            return [e for e in seen if e.kind == kind]

        async def wait(kind: str, n: int = 1, timeout_s: float = 120.0) -> None:
            if not await ctx.wait_until(lambda: len(of(kind)) >= n, timeout_s):
                raise ScenarioFailed(f"no {kind} (#{n}); events: {[e.kind for e in seen][-8:]}")

        ctx.world.set_battery_voltage(7.4)
        ctx.press("start_tour")
        await wait("tour.stop")
        # Sags on the leg to the second stop: low (< 6.6 V), not critical (< 6.3 V, issue 11's
        # stop-and-ask-for-help level) even with the load sag while driving.
        ctx.world.set_battery_voltage(6.55)
        await wait("battery.low")
        await wait("path.finished")  # the home path
        finished = of("path.finished")[-1]
        ctx.check("went home", finished.detail["path_id"] == 0, str(finished.detail))
        ctx.world.set_battery_voltage(6.8)  # better, but not yet ok
        await ctx.sleep(3.0)
        ctx.press("start_tour")
        await wait("bt.command_rejected")
        ctx.check("tour refused while low", "battery is low" in
                  of("bt.command_rejected")[-1].detail["message"])
        ctx.world.set_battery_voltage(7.3)
        await wait("battery.ok")
        ctx.press("start_tour")
        await wait("tour.stop", 3, 180.0)
        ctx.check("one low-battery episode", len(of("battery.low")) == 1)
        truth = ctx.truth()
        ctx.check("toured again", truth is not None and truth.x > 1.0, str(truth))


@pytest.mark.slow
async def test_low_battery_during_a_tour(tmp_path: Path) -> None:
    cfg = load_config(REPO_ROOT / "config.toml",
                      [f'data_dir="{tmp_path / "data"}"', "web.enabled=false"])
    report = await run_scenario(LowBatteryTour(), cfg, ScenarioArgs(seed=1))
    assert report["success"], (report["failure"], report["checks"])
    kinds = [e["kind"] for e in report["events"]]
    assert kinds.count("battery.low") == 1 and kinds.count("battery.ok") == 1
    assert report["collisions"] == 0
