"""The battery model: a NiMH pack read only as a voltage (docs/unattended.md, "The battery").

Curio has no current sensor: the only measurement is the servo supply voltage (each LX-16A's
``SERVO_VIN_READ``, the median sent by the Arduino at 1 Hz, hardware.md §3.1). So:

* **State of charge** comes from the resting voltage through the pack's open-circuit voltage
  curve, ``power.ocv_table`` (state of charge 0..1 → volts per cell, linear between rows) times
  ``power.cells``. The default is a generic NiMH curve, anchored on the pack figures of
  hardware.md §7.1 (6 cells, 5 Ah: about 8.4 V just off the charger, 7.2 V nominal, 6.0 V
  empty, i.e. 1.40 / 1.20 / 1.00 V per cell) and shaped like the 0.2 C discharge curves NiMH
  makers publish: a steep first 10 %, a long flat plateau of 1.2–1.3 V per cell, a knee below
  1.1 V in the last 5–10 %. Fit it to the real pack (log the voltage through one full
  discharge at the tour load) and set ``power.ocv_table``.
* The voltage sags under load (the simulator models 0.25 V at full duty) and the servo reads
  are noisy, so the voltage is low-passed first (:class:`VoltageFilter`, ``power.filter_s``).
  On the flat plateau a few tens of millivolts move the estimate by 10–20 %: the state of
  charge is coarse there, good at both ends, which is where the decisions are taken.
* **Time left** is the state of charge over its rate of fall, fitted by least squares over the
  last ``power.trend_window_s`` (:class:`TrendEstimator`); until a trend exists (a minute of
  falling samples) it is the charge left over ``power.average_current_a``.
* **Levels** (:func:`battery_level`): ``low`` below ``bt.low_battery_v`` (dock), ``critical``
  below ``bt.critical_battery_v`` (stop and ask for help), both back to ``ok`` only at
  ``bt.battery_ok_v`` (hysteresis: the voltage recovers by the sag when the rover stops).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass

from curio.core.config import PowerConfig

__all__ = ["Level", "PackModel", "TrendEstimator", "VoltageFilter", "battery_level", "time_to"]

Level = str  # "ok" | "low" | "critical"


def battery_level(previous: Level, volts: float, low_v: float, ok_v: float,
                  critical_v: float) -> Level:
    """The battery level after a reading of ``volts``, with hysteresis.

    ``ok`` → ``low`` below ``low_v``; any → ``critical`` below ``critical_v``; ``low`` and
    ``critical`` → ``ok`` only at ``ok_v`` or above (a critical battery stays critical until
    it is charged, even when the voltage recovers from its sag above ``low_v``).
    """
    if volts < critical_v:
        return "critical"
    if previous in ("low", "critical"):
        return "ok" if volts >= ok_v else previous
    return "low" if volts < low_v else "ok"


@dataclass(frozen=True)
class PackModel:
    """The pack's open-circuit voltage curve (see the module docstring).

    Args:
        cells: cells in series.
        capacity_ah: rated capacity, ampere-hours.
        table: ``(soc 0..1, volts per cell)`` rows, both increasing.
    """

    cells: int
    capacity_ah: float
    table: tuple[tuple[float, float], ...]

    @classmethod
    def from_config(cls, cfg: PowerConfig) -> PackModel:
        """The model of ``[power]``."""
        return cls(cfg.cells, cfg.capacity_ah, tuple((float(s), float(v))
                                                     for s, v in cfg.ocv_table))

    @property
    def full_v(self) -> float:
        """Pack voltage at 100 %, volts."""
        return self.table[-1][1] * self.cells

    @property
    def empty_v(self) -> float:
        """Pack voltage at 0 %, volts."""
        return self.table[0][1] * self.cells

    def soc(self, pack_v: float) -> float:
        """State of charge 0..1 at a resting pack voltage (clamped at both ends)."""
        if not math.isfinite(pack_v):
            return 0.0
        v = pack_v / self.cells
        rows = self.table
        if v <= rows[0][1]:
            return 0.0
        for (s0, v0), (s1, v1) in itertools.pairwise(rows):
            if v <= v1:
                return s0 + (s1 - s0) * (v - v0) / (v1 - v0)
        return 1.0

    def volts(self, soc: float) -> float:
        """Resting pack voltage at a state of charge 0..1 (clamped)."""
        s = min(1.0, max(0.0, soc))
        rows = self.table
        for (s0, v0), (s1, v1) in itertools.pairwise(rows):
            if s <= s1:
                return self.cells * (v0 + (v1 - v0) * (s - s0) / (s1 - s0))
        return self.cells * rows[-1][1]


class VoltageFilter:
    """First-order low-pass of the pack voltage with time constant ``tau_s`` (0: raw).

    The first reading, and any reading after :meth:`reset` (the charger was connected or
    removed: the voltage steps), is taken as it is.
    """

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.value: float | None = None
        self._t: float | None = None

    def reset(self) -> None:
        """Forget the history (the next reading is taken as it is)."""
        self.value = None
        self._t = None

    def update(self, stamp_s: float, volts: float) -> float:
        """Feed a reading at clock time ``stamp_s``; return the filtered voltage."""
        if self.value is None or self._t is None or self.tau_s <= 0.0:
            self.value, self._t = volts, stamp_s
            return volts
        dt = max(0.0, stamp_s - self._t)
        self._t = stamp_s
        k = 1.0 - math.exp(-dt / self.tau_s)
        self.value += k * (volts - self.value)
        return self.value


class TrendEstimator:
    """The rate of change of the state of charge, fitted over a sliding window.

    Args:
        window_s: the fit uses the samples of the last ``window_s`` seconds.
        min_span_s: no rate before the samples span this long.
    """

    def __init__(self, window_s: float, min_span_s: float = 60.0) -> None:
        self.window_s = window_s
        self.min_span_s = min_span_s
        self._samples: deque[tuple[float, float]] = deque()

    def reset(self) -> None:
        """Forget the samples (charging started or stopped)."""
        self._samples.clear()

    def add(self, stamp_s: float, soc: float) -> None:
        """One state-of-charge sample at clock time ``stamp_s``."""
        self._samples.append((stamp_s, soc))
        while self._samples and stamp_s - self._samples[0][0] > self.window_s:
            self._samples.popleft()

    def rate_per_s(self) -> float | None:
        """d(soc)/dt by least squares, per second (None: too few or too short)."""
        pts = self._samples
        if len(pts) < 3 or pts[-1][0] - pts[0][0] < self.min_span_s:
            return None
        n = len(pts)
        mt = sum(t for t, _ in pts) / n
        ms = sum(s for _, s in pts) / n
        var = sum((t - mt) ** 2 for t, _ in pts)
        if var <= 0.0:
            return None
        return sum((t - mt) * (s - ms) for t, s in pts) / var


def time_to(soc_now: float, soc_target: float, rate_per_s: float | None,
            fallback_per_s: float) -> float | None:
    """Seconds until the state of charge falls from ``soc_now`` to ``soc_target`` at
    ``rate_per_s`` (a fall; rises and flat trends use ``fallback_per_s``, a positive fall
    rate); 0 when already there, None when no rate is known."""
    if soc_now <= soc_target:
        return 0.0
    rate = -rate_per_s if rate_per_s is not None and rate_per_s < -1e-9 else fallback_per_s
    if rate <= 0.0:
        return None
    return (soc_now - soc_target) / rate
