"""The progress monitor: closer to the goal along the plan, or stalled."""

from __future__ import annotations

import math

from curio.nav.navigator.progress import Progress, ProgressMonitor


def monitor(plan_m: float = 10.0, at_s: float = 0.0) -> ProgressMonitor:
    m = ProgressMonitor(20.0)
    m.on_plan(plan_m, at_s)
    return m


def test_the_first_plan_is_the_baseline() -> None:
    m = ProgressMonitor(20.0)
    assert m.best_remaining_m == math.inf
    m.on_plan(10.0, 5.0)
    assert m.best_remaining_m == 10.0
    assert m.update(10.0, 25.0) is Progress.STEADY  # 20 s: not yet
    assert m.update(10.0, 25.1) is Progress.STALLED


def test_0_3_m_closer_is_progress_and_restarts_the_clock() -> None:
    m = monitor()
    assert m.update(9.75, 1.0) is Progress.STEADY  # 0.25 m: not enough
    assert m.update(9.65, 2.0) is Progress.IMPROVED
    assert m.best_remaining_m == 9.65
    assert m.update(9.65, 22.0) is Progress.STEADY
    assert m.update(9.65, 22.1) is Progress.STALLED


def test_stalled_starts_the_clock_again() -> None:
    m = monitor()
    assert m.update(10.0, 20.5) is Progress.STALLED
    assert m.update(10.0, 40.5) is Progress.STEADY
    assert m.update(10.0, 40.6) is Progress.STALLED


def test_pause_does_not_count_the_time_held() -> None:
    m = monitor()
    m.pause(15.0)
    assert m.update(10.0, 35.0) is Progress.STEADY
    assert m.update(10.0, 35.1) is Progress.STALLED


def test_a_detour_resets_the_baseline_once_per_timeout() -> None:
    m = monitor(10.0, at_s=0.0)
    m.on_plan(12.0, 10.0)  # a detour, but the baseline is only 10 s old
    assert m.best_remaining_m == 10.0
    m.on_plan(11.0, 25.0)  # 1 m longer is no detour
    assert m.best_remaining_m == 10.0
    m.on_plan(11.5, 25.0)  # a detour 25 s after the baseline: the new baseline
    assert m.best_remaining_m == 11.5
    assert m.update(11.5, 44.0) is Progress.STEADY  # its clock starts at 25 s
    m.on_plan(14.0, 44.5)  # flickering back to a long route within the timeout: kept
    assert m.best_remaining_m == 11.5


def test_reset_makes_the_next_plan_the_baseline() -> None:
    m = monitor(10.0)
    m.update(2.0, 1.0)
    m.reset()
    m.on_plan(30.0, 2.0)
    assert m.best_remaining_m == 30.0
