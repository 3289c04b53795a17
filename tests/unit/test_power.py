"""The battery model and the power monitor (state of charge, time left, levels, charging)."""

from __future__ import annotations

import pytest

from curio.core.config import Config, PowerConfig
from curio.core.messages import BatteryState
from curio.core.topics import EVENTS, POWER, make_bus
from curio.power.model import PackModel, TrendEstimator, VoltageFilter, battery_level, time_to
from curio.power.monitor import PowerMonitor

from .bt_fakes import ManualClock


def test_the_pack_curve_is_the_documented_nimh_pack() -> None:
    pack = PackModel.from_config(PowerConfig())
    assert pack.full_v == pytest.approx(8.4) and pack.empty_v == pytest.approx(6.0)
    assert pack.soc(6 * 1.21) == pytest.approx(0.4)  # a row of the table
    assert pack.soc(7.2) == pytest.approx(1 / 3)  # 1.20 V per cell: between 1.18 and 1.21
    assert pack.soc(5.0) == 0.0 and pack.soc(9.0) == 1.0
    for soc in (0.0, 0.03, 0.33, 0.5, 0.87, 1.0):
        assert pack.soc(pack.volts(soc)) == pytest.approx(soc)
    volts = [pack.volts(s / 20) for s in range(21)]
    assert volts == sorted(volts)


def test_levels_have_hysteresis_and_critical_latches_until_charged() -> None:
    def level(prev: str, v: float) -> str:
        return battery_level(prev, v, low_v=6.6, ok_v=7.0, critical_v=6.3)

    assert level("ok", 6.7) == "ok" and level("ok", 6.59) == "low"
    assert level("low", 6.9) == "low" and level("low", 7.0) == "ok"
    assert level("low", 6.29) == "critical" and level("ok", 6.0) == "critical"
    assert level("critical", 6.8) == "critical"  # recovered from the sag: still critical
    assert level("critical", 7.0) == "ok"


def test_filter_and_trend() -> None:
    f = VoltageFilter(10.0)
    assert f.update(0.0, 7.0) == 7.0
    v = f.update(10.0, 6.0)
    assert 6.3 < v < 6.4  # one time constant: 63 % of the step
    f.reset()
    assert f.update(11.0, 8.0) == 8.0
    trend = TrendEstimator(600.0, min_span_s=60.0)
    for t in range(0, 50, 10):
        trend.add(float(t), 0.5 - t * 1e-4)
    assert trend.rate_per_s() is None  # less than a minute
    for t in range(50, 200, 10):
        trend.add(float(t), 0.5 - t * 1e-4)
    assert trend.rate_per_s() == pytest.approx(-1e-4)
    assert time_to(0.5, 0.0, -1e-4, 1.0) == pytest.approx(5000.0)
    assert time_to(0.5, 0.0, None, 1e-3) == pytest.approx(500.0)  # the fallback rate


def test_monitor_publishes_soc_time_left_and_charging() -> None:
    bus = make_bus()
    clock = ManualClock()
    cfg = Config()
    mon = PowerMonitor(cfg, bus, clock)  # type: ignore[arg-type]
    events = bus.subscribe(EVENTS)
    v = 7.6
    for t in range(0, 400, 5):
        v -= 0.002
        mon.on_battery(BatteryState(float(t), v, charger_v=0.0))
    state = bus.latest(POWER)
    assert state is not None and not state.charging and state.level == "ok"
    assert 0.5 < state.soc < 0.7
    # 0.4 mV/s on the plateau (0.18 V per 20 %): about half an hour left, from the fitted
    # trend, not the 2 h of the fallback (60 % of 5 Ah at 1.5 A).
    assert state.time_left_s is not None and 1000.0 < state.time_left_s < 3000.0
    assert state.time_to_low_s is not None and state.time_to_low_s < state.time_left_s
    mon.on_battery(BatteryState(401.0, 7.8, charger_v=9.0))
    state = bus.latest(POWER)
    assert state is not None and state.charging and state.time_left_s is None
    assert state.time_to_full_s is not None and state.time_to_full_s > 0
    (ev,) = [e for e in events.drain() if e.kind == "power.charging"]
    assert ev.detail["charging"] is True
    mon.on_battery(BatteryState(402.0, 6.5, charger_v=None))
    assert bus.latest(POWER).level == "low"  # type: ignore[union-attr]
