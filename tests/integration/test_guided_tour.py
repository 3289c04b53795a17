"""The guided tour on the whole simulated app: stops announced in order, then home."""

from __future__ import annotations

import pytest

from curio.core.config import Config, TourStopConfig
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, ScenarioFailed, run_scenario


async def test_guided_tour_visits_stops_in_order_and_returns_home(cfg: Config) -> None:
    stops = [
        TourStopConfig(name="Lobby", x_m=2.0, y_m=-2.5, dwell_s=2.0, message="Welcome!"),
        TourStopConfig(name="Gallery", x_m=12.5, y_m=1.5, dwell_s=2.0, message="The gallery."),
    ]
    cfg = cfg.model_copy(update={"bt": cfg.bt.model_copy(update={"tour_stops": stops})})
    report = await run_scenario(get_scenario("guided-tour"), cfg, ScenarioArgs(seed=3))
    assert report["success"], report["failure"]
    assert report["goals_reached"] == report["goals_total"] == 3
    assert report["collisions"] == 0
    stop_events = [e for e in report["events"] if e["kind"] == "tour.stop"]
    assert [e["detail"]["name"] for e in stop_events] == ["Lobby", "Gallery"]
    assert [e["detail"]["message"] for e in stop_events] == ["Welcome!", "The gallery."]
    assert {c["name"] for c in report["checks"]} >= {"back home", "every stop announced in order"}


async def test_guided_tour_without_stops_fails_clearly(cfg: Config) -> None:
    cfg = cfg.model_copy(update={"bt": cfg.bt.model_copy(update={"tour_stops": []})})
    with pytest.raises(ScenarioFailed, match=r"needs bt\.tour_stops"):
        await run_scenario(get_scenario("guided-tour"), cfg, ScenarioArgs(seed=1))
