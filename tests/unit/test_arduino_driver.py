"""Pure parts of the Arduino driver: mapping the Mega's millis() to host time."""

from __future__ import annotations

import numpy as np
import pytest

from curio.drivers.arduino.driver import McuClock


def test_mcu_clock_removes_latency_jitter() -> None:
    rng = np.random.default_rng(4)
    clock = McuClock()
    offset_s = 1000.0 - 0.250  # host time when the MCU booted
    errors = []
    for k in range(200):
        t_ms = 250 + 33 * k
        true_s = offset_s + t_ms / 1000.0
        latency = 0.002 + float(rng.exponential(0.004))  # USB + loop jitter
        stamp = clock.to_host(t_ms, true_s + latency)
        assert stamp <= true_s + latency  # never after receipt
        if k > 30:
            errors.append(stamp - true_s)
    # The fastest report sets the offset: stamps sit within the minimum latency of the truth,
    # much tighter than the receipt times (mean latency about 6 ms, spread several ms).
    assert max(errors) - min(errors) < 0.004
    assert float(np.mean(errors)) == pytest.approx(0.002, abs=0.0015)


def test_mcu_clock_follows_drift_and_restarts_after_reset() -> None:
    clock = McuClock(window=30)
    drift = 1.005  # host runs 0.5 % faster than the Mega's resonator
    last = 0.0
    for k in range(300):
        t_ms = 33 * k
        last = clock.to_host(t_ms, t_ms / 1000.0 * drift + 0.003)
    assert last == pytest.approx(33 * 299 / 1000.0 * drift + 0.003, abs=0.006)
    # The Mega resets: t_ms starts again near 0 and the estimate starts over.
    assert clock.to_host(100, 500.0) == pytest.approx(500.0)
    assert clock.to_host(133, 500.040) == pytest.approx(500.033, abs=1e-6)


def test_mcu_clock_adds_the_read_offset() -> None:
    clock = McuClock()
    assert clock.to_host(1000, 10.0) == pytest.approx(10.0)
    assert clock.to_host(1033, 10.050, extra_ms=5.0) == pytest.approx(10.038)
