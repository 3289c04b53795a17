"""The pose history: linear and SE(2) interpolation, nearest, bounds, resets.

The reference functions are the three lookups the history replaced (the costmap's, the
localiser's and the mapper's), kept here word for word: the history must give bit-identical
answers, or same-seed scenario reports would change.
"""

from __future__ import annotations

import bisect
import itertools
import math

import numpy as np
import pytest

from curio.core.geometry import Pose2D, wrap_angle
from curio.core.pose_history import PoseHistory


def costmap_pose_at(poses: list[tuple[float, Pose2D]], stamp: float) -> Pose2D:
    t_last, p_last = poses[-1]
    if stamp >= t_last or len(poses) == 1:
        return p_last
    if stamp <= poses[0][0]:
        return poses[0][1]
    t1, p1 = poses[-1]
    for t0, p0 in reversed(poses):
        if t0 <= stamp:
            a = 0.0 if t1 == t0 else (stamp - t0) / (t1 - t0)
            return Pose2D(p0.x + a * (p1.x - p0.x), p0.y + a * (p1.y - p0.y),
                          wrap_angle(p0.yaw + a * wrap_angle(p1.yaw - p0.yaw)))
        t1, p1 = t0, p0
    return p_last


def localizer_odom_at(poses: list[tuple[float, Pose2D]], stamp: float) -> Pose2D:
    stamps = [t for t, _ in poses]
    i = bisect.bisect_left(stamps, stamp)
    if i <= 0:
        return poses[0][1]
    if i >= len(poses):
        return poses[-1][1]
    (ta, a), (tb, b) = poses[i - 1], poses[i]
    span = tb - ta
    f = 0.0 if span <= 0 else (stamp - ta) / span
    d = a.inverse() @ b
    return a @ Pose2D(d.x * f, d.y * f, d.yaw * f)


def mapper_odom_for(poses: list[tuple[float, Pose2D]], stamp: float) -> Pose2D:
    return min(poses[-20:], key=lambda o: abs(o[0] - stamp))[1]


def trajectory(seed: int, n: int = 60) -> list[tuple[float, Pose2D]]:
    """A noisy drive with irregular (and some repeated) stamps, crossing ±π."""
    rng = np.random.default_rng(seed)
    t, x, y, yaw = 10.0, 0.0, 0.0, 2.9
    out = []
    for _ in range(n):
        t += float(rng.choice([0.0, 0.02, 0.05, 0.1]))
        x += float(rng.normal(0.0, 0.05))
        y += float(rng.normal(0.0, 0.05))
        yaw = wrap_angle(yaw + float(rng.normal(0.0, 0.2)))
        out.append((t, Pose2D(x, y, yaw)))
    return out


def history(poses: list[tuple[float, Pose2D]], maxlen: int = 256,
            interpolation: str = "linear") -> PoseHistory:
    h = PoseHistory(maxlen, interpolation=interpolation)  # type: ignore[arg-type]
    for t, p in poses:
        h.add(t, p)
    return h


def probe_stamps(poses: list[tuple[float, Pose2D]]) -> list[float]:
    """Before, after, on and between the stamps."""
    ts = [t for t, _ in poses]
    mids = [0.5 * (a + b) for a, b in itertools.pairwise(ts)]
    thirds = [a + (b - a) / 3.0 for a, b in itertools.pairwise(ts)]
    return [ts[0] - 1.0, math.inf, ts[-1] + 0.01, *ts, *mids, *thirds]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_linear_is_bit_identical_to_the_costmaps_lookup(seed: int) -> None:
    poses = trajectory(seed)
    h = history(poses)
    for stamp in probe_stamps(poses):
        assert h.at(stamp) == costmap_pose_at(poses, stamp), stamp


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_se2_is_bit_identical_to_the_localisers_lookup(seed: int) -> None:
    poses = trajectory(seed)
    h = history(poses, interpolation="se2")
    for stamp in probe_stamps(poses):
        assert h.at(stamp) == localizer_odom_at(poses, stamp), stamp


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_nearest_is_the_mappers_lookup(seed: int) -> None:
    poses = trajectory(seed)
    h = history(poses, maxlen=20)
    for stamp in probe_stamps(poses):
        assert h.nearest(stamp) == mapper_odom_for(poses, stamp), stamp


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_two_interpolations_agree_up_to_rounding(seed: int) -> None:
    poses = trajectory(seed)
    lin, se2 = history(poses), history(poses, interpolation="se2")
    stamps = {t for t, _ in poses}
    # Between stamps (on a repeated stamp the linear lookup takes the last of the poses, the
    # SE(2) one the first).
    for stamp in (t for t in probe_stamps(poses)[3:] if t not in stamps):
        p, q = lin.at(stamp), se2.at(stamp)
        assert p is not None and q is not None
        assert (p.x, p.y) == pytest.approx((q.x, q.y), abs=1e-12)
        assert abs(wrap_angle(p.yaw - q.yaw)) < 1e-12


def test_the_heading_goes_the_short_way_round() -> None:
    h = history([(0.0, Pose2D(0.0, 0.0, 3.0)), (1.0, Pose2D(0.0, 0.0, -3.0))])
    mid = h.at(0.5)
    assert mid is not None and abs(mid.yaw) == pytest.approx(math.pi)


def test_empty_latest_and_len() -> None:
    h = PoseHistory(3)
    assert h.at(1.0) is None and h.nearest(1.0) is None and h.latest() is None
    assert not h and len(h) == 0
    for k in range(5):
        h.add(float(k), Pose2D(float(k), 0.0))
    assert len(h) == 3 and h.latest() == (4.0, Pose2D(4.0, 0.0))
    assert h.at(0.0) == Pose2D(2.0, 0.0)  # the oldest kept


def test_time_going_back_starts_over() -> None:
    h = history([(5.0, Pose2D(5.0, 0.0)), (6.0, Pose2D(6.0, 0.0))])
    h.add(1.0, Pose2D(1.0, 0.0))
    assert len(h) == 1 and h.at(5.5) == Pose2D(1.0, 0.0)
    h.add(1.0, Pose2D(2.0, 0.0))  # the same stamp again is not going back
    assert len(h) == 2


def test_a_stamped_history_of_any_item_and_without_a_limit() -> None:
    from curio.core.pose_history import StampedHistory

    h: StampedHistory[str] = StampedHistory(None)
    for k in range(1000):
        h.add(k * 0.1, f"m{k}")
    assert len(h) == 1000 and h.nearest(50.04) == "m500" and h.nearest(-5.0) == "m0"
    ties: StampedHistory[str] = StampedHistory(None)
    ties.add(1.0, "a")
    ties.add(2.0, "b")
    assert ties.nearest(1.5) == "a"  # a tie: the older
    h.add(1.0, "reset")
    assert h.latest() == (1.0, "reset") and len(h) == 1
