"""Where a replay diverges from its recording: poses, plans and velocity commands.

Each series is a list of ``(t_s, message)`` in clock time (the recording's ``publish_time``; the
replay runs on the same clock times). Every recorded message is compared with the replayed
message *in effect* at its time — the latest one published at or before it (``HOLD_EPS_S``
allows for the nanosecond rounding of recorded times) — so a replay that reproduces the run
compares each message with its twin (error 0), and one that drifts is measured where the
recording was.

* poses (``/pose``): position error (m) and yaw error (rad); divergence above ``pose_tol_m``;
* plans (``/plan``): the symmetric Hausdorff distance between the two paths (m); above
  ``plan_tol_m``, or a plan on one side only, is a divergence;
* commands (``/cmd_vel``, ``/cmd_vel_nav``): speed and yaw-rate differences; above
  ``cmd_tol_mps`` / ``cmd_tol_radps``.

Every figure is reported with the first time (seconds from the replay's start) it went over its
tolerance, and how often. Recorded messages older than the replay's first (a replay started
mid-run needs a moment for its first pose) are counted in ``before_first_replayed``, not
compared.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from curio.core.geometry import angle_diff
from curio.core.messages import Odometry, Path, PoseWithCovariance, Twist

__all__ = ["Tolerances", "compare_paths", "compare_poses", "compare_twists", "truth_rmse"]

HOLD_EPS_S = 2e-9
T = TypeVar("T")
Series = Sequence[tuple[float, T]]


@dataclass(frozen=True)
class Tolerances:
    """What counts as a divergence."""

    pose_tol_m: float = 0.001
    pose_tol_rad: float = 0.002
    plan_tol_m: float = 0.05
    cmd_tol_mps: float = 0.01
    cmd_tol_radps: float = 0.02


def _held(series: Series[T], t: float, k: int = 0) -> T | None:
    """The message of ``series`` in effect at ``t``: the ``k``-th of those published at that
    very instant if there are that many (a plan cleared and replaced at once), else the latest
    at or before it; None before the first."""
    hi = bisect.bisect_right(series, t + HOLD_EPS_S, key=lambda item: item[0])
    lo = bisect.bisect_left(series, t - HOLD_EPS_S, key=lambda item: item[0])
    if hi - lo > k:
        return series[lo + k][1]
    return series[hi - 1][1] if hi > 0 else None


def _scan(recorded: Series[T], replayed: Series[T], t0: float,
          errors: Callable[[T, T], tuple[float, ...]],
          limits: tuple[float, ...]) -> dict[str, Any]:
    """Compare every recorded message with the replayed one in effect; per error: max and RMS;
    overall: how many went over a limit and when first."""
    worst = [0.0] * len(limits)
    sq = [0.0] * len(limits)
    over = 0
    first: float | None = None
    same = 0  # how many recorded messages came before this one at the same instant
    before_first = 0  # recorded before the replay published any: nothing to compare with
    for i, (t, rec) in enumerate(recorded):
        same = same + 1 if i and recorded[i - 1][0] == t else 0
        held = _held(replayed, t, same)
        if held is None:
            before_first += 1
            continue
        errs = errors(rec, held)
        for k, e in enumerate(errs):
            worst[k] = max(worst[k], e)
            sq[k] += e * e if math.isfinite(e) else 0.0
        if any(e > lim for e, lim in zip(errs, limits, strict=True)):
            over += 1
            if first is None:
                first = t - t0
    n = max(1, len(recorded))
    return {"recorded": len(recorded), "replayed": len(replayed), "over_tolerance": over,
            "before_first_replayed": before_first,
            "first_divergence_s": None if first is None else round(first, 3),
            "max": [_r(w) for w in worst], "rms": [_r(math.sqrt(s / n)) for s in sq]}


def _r(v: float) -> float | None:
    return round(v, 9) if math.isfinite(v) else None


def compare_poses(recorded: Series[PoseWithCovariance], replayed: Series[PoseWithCovariance],
                  t0: float, tol: Tolerances) -> dict[str, Any]:
    """Pose errors: ``max_error_m``, ``rms_error_m``, ``max_yaw_error_rad`` and the rest."""
    def errors(a: PoseWithCovariance, b: PoseWithCovariance) -> tuple[float, float]:
        return a.pose.distance_to(b.pose), abs(angle_diff(a.pose.yaw, b.pose.yaw))

    out = _scan(recorded, replayed, t0, errors, (tol.pose_tol_m, tol.pose_tol_rad))
    (max_m, max_rad), (rms_m, _) = out.pop("max"), out.pop("rms")
    return {**out, "max_error_m": max_m, "rms_error_m": rms_m, "max_yaw_error_rad": max_rad}


def _hausdorff(a: Path, b: Path) -> float:
    if not a.poses or not b.poses:
        return 0.0 if not a.poses and not b.poses else math.inf
    pa = np.array([(p.x, p.y) for p in a.poses])
    pb = np.array([(p.x, p.y) for p in b.poses])
    d = np.sqrt(((pa[:, None, :] - pb[None, :, :]) ** 2).sum(axis=2))
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))


def compare_paths(recorded: Series[Path], replayed: Series[Path], t0: float,
                  tol: Tolerances) -> dict[str, Any]:
    """Plan differences: ``max_hausdorff_m`` (inf: a plan on one side only)."""
    out = _scan(recorded, replayed, t0, lambda a, b: (_hausdorff(a, b),), (tol.plan_tol_m,))
    out.pop("rms")
    return {**out, "max_hausdorff_m": out.pop("max")[0]}


def compare_twists(recorded: Series[Twist], replayed: Series[Twist], t0: float,
                   tol: Tolerances) -> dict[str, Any]:
    """Command differences: ``max_linear_diff_mps``, ``max_angular_diff_radps``."""
    def errors(a: Twist, b: Twist) -> tuple[float, float]:
        return abs(a.linear_mps - b.linear_mps), abs(a.angular_radps - b.angular_radps)

    out = _scan(recorded, replayed, t0, errors, (tol.cmd_tol_mps, tol.cmd_tol_radps))
    out.pop("rms")
    lin, ang = out.pop("max")
    return {**out, "max_linear_diff_mps": lin, "max_angular_diff_radps": ang}


def truth_rmse(poses: Series[PoseWithCovariance], truth: Series[Odometry]) -> float | None:
    """RMS distance of estimated poses from the simulator's ground truth in effect (m)."""
    sq, n = 0.0, 0
    for t, est in poses:
        true = _held(truth, t)
        if true is not None:
            sq += est.pose.distance_to(true.pose) ** 2
            n += 1
    return round(math.sqrt(sq / n), 6) if n else None
