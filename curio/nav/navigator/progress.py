"""The progress monitor: is the rover getting closer to its goal along the plan?

The local controller's own progress checker asks whether the rover moves at all; this one
(Nav2's ``ProgressChecker``, measured along the plan) asks whether it gets closer to the
waypoint. It keeps the best distance remaining (metres, along the plan) and when it was
reached (clock seconds):

* a distance ``min_gain_m`` (0.3 m) below the best is progress (:attr:`Progress.IMPROVED`);
* no progress for ``nav.recovery.goal_progress_timeout_s`` is :attr:`Progress.STALLED`
  (and the clock starts again, so the next verdict comes one timeout later);
* a new plan sets the baseline: the first one of a waypoint, and a genuine detour (longer by
  more than ``detour_m`` = 1 m), at most once per timeout so plans that flicker between two
  routes cannot keep postponing the verdict;
* time spent holding (no pose) or in a recovery action does not count (:meth:`pause`).
"""

from __future__ import annotations

import enum
import math

__all__ = ["Progress", "ProgressMonitor"]


class Progress(enum.Enum):
    """The monitor's verdict on one cycle."""

    IMPROVED = "improved"
    STEADY = "steady"
    STALLED = "stalled"


class ProgressMonitor:
    """Progress towards the goal along the plan (see the module docstring).

    Args:
        timeout_s: no progress for this long is stalled, seconds.
        min_gain_m: how much closer counts as progress, metres.
        detour_m: a new plan longer than the best by more than this resets the baseline.
    """

    def __init__(self, timeout_s: float, min_gain_m: float = 0.3, detour_m: float = 1.0) -> None:
        self.timeout_s = timeout_s
        self.min_gain_m = min_gain_m
        self.detour_m = detour_m
        self.best_remaining_m = math.inf
        self._best_t = 0.0
        self._baseline_t = -math.inf

    def reset(self) -> None:
        """A new goal or the next waypoint: the next plan sets the baseline."""
        self.best_remaining_m = math.inf

    def pause(self, now_s: float) -> None:
        """Time up to ``now_s`` does not count (the rover held still or ran a recovery)."""
        self._best_t = now_s

    def on_plan(self, length_m: float, now_s: float) -> None:
        """A new plan of ``length_m``: the baseline for the first one and for a detour."""
        if not math.isfinite(self.best_remaining_m) or (
                length_m > self.best_remaining_m + self.detour_m
                and now_s - self._baseline_t > self.timeout_s):
            self.best_remaining_m = length_m
            self._best_t = now_s
            self._baseline_t = now_s

    def update(self, remaining_m: float, now_s: float) -> Progress:
        """Judge the distance remaining along the plan at clock time ``now_s``."""
        if remaining_m < self.best_remaining_m - self.min_gain_m:
            self.best_remaining_m = remaining_m
            self._best_t = now_s
            return Progress.IMPROVED
        if now_s - self._best_t > self.timeout_s:
            self._best_t = now_s
            return Progress.STALLED
        return Progress.STEADY
