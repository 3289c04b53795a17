"""The power monitor: ``/battery`` in, ``/power`` out (state of charge, time left, level).

:class:`PowerMonitor` is a part: for every ``/battery`` reading it low-passes the voltage, reads
the state of charge off the pack's curve (:class:`~curio.power.model.PackModel`), fits the time
left (:class:`~curio.power.model.TrendEstimator`), applies the level hysteresis the behaviour
tree uses (:func:`~curio.power.model.battery_level`, on the raw reading like the tree) and
publishes a :class:`~curio.core.messages.PowerState` on ``/power`` for the dashboard, the
kiosk and the docking behaviour. Charging is the dock contacts' voltage
(``BatteryState.charger_v``) above ``power.charger_detect_v``; a change of it resets the filter
and the trend (the voltage steps when the charger is connected or removed). Events:
``power.charging`` (``charging`` true/false, ``voltage_v``, ``soc``).
"""

from __future__ import annotations

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import BatteryState, Event, PowerState
from curio.core.topics import BATTERY, EVENTS, POWER

from .model import PackModel, TrendEstimator, VoltageFilter, battery_level, time_to

__all__ = ["PowerMonitor"]


class PowerMonitor:
    """Turns ``/battery`` readings into ``/power`` (see the module docstring).

    Args:
        cfg: the whole configuration (``[power]`` and the levels of ``[bt]``).
        bus, clock: injected.
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock) -> None:
        self.cfg = cfg
        self.bus = bus
        self.clock = clock
        self.model = PackModel.from_config(cfg.power)
        self.filter = VoltageFilter(cfg.power.filter_s)
        self.trend = TrendEstimator(cfg.power.trend_window_s)
        self.level = "ok"
        self.charging: bool | None = None
        self.latest: PowerState | None = None

    def on_battery(self, msg: BatteryState) -> PowerState:
        """Process one reading; publish and return the new state."""
        pcfg, bt = self.cfg.power, self.cfg.bt
        charging = msg.charger_v is not None and msg.charger_v > pcfg.charger_detect_v
        if charging != self.charging:
            if self.charging is not None:
                self.bus.publish(EVENTS, Event(msg.stamp, "power.charging", {
                    "charging": charging, "voltage_v": round(msg.voltage_v, 3)}))
            self.charging = charging
            self.filter.reset()
            self.trend.reset()
        volts = self.filter.update(msg.stamp, msg.voltage_v)
        self.level = battery_level(self.level, msg.voltage_v, bt.low_battery_v,
                                   bt.battery_ok_v, bt.critical_battery_v)
        soc = self.model.soc(volts)
        self.trend.add(msg.stamp, soc)
        left = low = full = None
        if charging:
            full = (1.0 - soc) * pcfg.capacity_ah * 3600.0 / pcfg.charge_current_a
        else:
            rate = self.trend.rate_per_s()
            fallback = pcfg.average_current_a / (pcfg.capacity_ah * 3600.0)
            left = time_to(soc, 0.0, rate, fallback)
            low = time_to(soc, self.model.soc(bt.low_battery_v), rate, fallback)
        state = PowerState(msg.stamp, round(volts, 4), round(msg.voltage_v, 4), round(soc, 4),
                           _round(left), _round(low), _round(full), charging, self.level)
        self.latest = state
        self.bus.publish(POWER, state)
        return state

    async def run(self) -> None:
        """Follow ``/battery`` until cancelled."""
        sub = self.bus.subscribe(BATTERY)
        try:
            async for msg in sub:
                self.on_battery(msg)
        finally:
            sub.close()


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 1)
