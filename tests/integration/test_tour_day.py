"""A shortened opening day on the whole simulated app: a scheduled tour starts at its time, a
visitor starts one at the kiosk, the next scheduled one is skipped with the reason while it
runs, the rover goes home between tours, and the event log holds the day for the report.

The full day (``curio sim tour-day``, ~40 s of wall time) is measured in docs/tours.md."""

from __future__ import annotations

from curio.core.config import Config
from curio.eventlog.report import daily_report
from curio.scenarios.base import ScenarioArgs, run_scenario
from curio.scenarios.tour_day import DAY, TourDayScenario


class ShortDay(TourDayScenario):
    """09:00-10:05: Highlights scheduled at 09:30 and 10:00; a visitor starts it at 09:59:50."""

    schedule = (("Highlights", ("09:30", "10:00")),)
    visitors = (("09:59:50", "Highlights"),)
    close = "10:05"
    door = None
    expect_skipped = "10:00"


async def test_a_short_opening_day(cfg: Config) -> None:
    cfg = cfg.model_copy(update={"tours": cfg.tours.model_copy(update={"start_window_s": 60.0})})
    scenario = ShortDay()
    report = await run_scenario(scenario, cfg, ScenarioArgs(seed=2))
    assert report["success"], (report["failure"], report["checks"])
    m = report["metrics"]
    assert (m["tours_scheduled"], m["tours_completed"], m["tours_skipped"]) == (2, 2, 1)
    assert m["stops_visited"] == 4 and m["help_requests"] == 0
    assert m["skip_reasons"] and "not ready within 60 s" in m["skip_reasons"][0]
    assert m["time_lapse_s"] > 1500.0  # the idle half hour before 09:30 was jumped
    kinds = [e["kind"] for e in report["events"]]
    started = [e["detail"] for e in report["events"] if e["kind"] == "tour.started"]
    assert [d["source"] for d in started] == ["scheduler", "kiosk"]
    assert kinds.count("tour.finished") == 2
    home = [e for e in report["events"] if e["kind"] == "bt.command_accepted"
            and e["detail"]["action"] == "go_home"]
    assert len(home) == 2 and all(e["detail"]["source"] == "tour" for e in home)
    # The day is in the event log (in the scenario's data directory) for the report.
    rep = m["report"]
    assert rep["tours_completed"] == 2 and rep["tours_skipped"] == 1
    assert rep["stops_visited"] == 4 and rep["distance_m"] > 20.0 and rep["moving_s"] > 60.0
    assert m["events_logged"] == rep["events"] > 40
    assert rep["timezone"] == cfg.tours.timezone and rep["day"] == DAY.isoformat()
    assert callable(daily_report)
