"""The robust pose graph and the loop-closure verification."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.estimation.loop_closure import Hypothesis, Keyframe, LoopCloser, LoopParams
from curio.estimation.pose_graph import PoseGraph, adjoint, to_local_info

INFO = np.diag([400.0, 400.0, 4000.0])


def _square_loop(laps: int = 2) -> list[Pose2D]:
    """Poses every metre round a 10 m square, ``laps`` times."""
    out = [Pose2D()]
    for k in range(1, 40 * laps):
        out.append(out[-1] @ Pose2D(1.0, 0.0, math.pi / 2 if k % 10 == 0 else 0.0))
    return out


def _drifting_graph(truth: list[Pose2D]) -> PoseGraph:
    g = PoseGraph()
    est = Pose2D()
    g.add_node(est)
    for k in range(1, len(truth)):
        z = truth[k - 1].inverse() @ truth[k]
        zn = Pose2D(z.x * 1.01, z.y + 0.01, z.yaw + 0.01)  # a curving drift
        est = est @ zn
        g.add_node(est)
        g.add_edge(k - 1, k, zn, INFO)
    return g


def _max_error(g: PoseGraph, truth: list[Pose2D]) -> float:
    return max(g.pose(k).distance_to(t) for k, t in enumerate(truth))


def test_loop_closures_undo_the_drift() -> None:
    truth = _square_loop()
    g = _drifting_graph(truth)
    before = _max_error(g, truth)
    for i, j in [(0, 40), (5, 45), (12, 52), (25, 65), (33, 73)]:
        g.add_edge(i, j, truth[i].inverse() @ truth[j], INFO, robust=True)
    g.optimize(robust=False)
    g.optimize()
    assert before > 2.0
    assert _max_error(g, truth) < 0.2 * before
    assert g.pose(0) == Pose2D()  # the gauge: node 0 does not move
    assert not g.outliers(30.0)


def test_one_wrong_closure_is_flagged_and_does_not_bend_the_map() -> None:
    truth = _square_loop()
    g = _drifting_graph(truth)
    for i, j in [(0, 40), (5, 45), (12, 52), (25, 65), (33, 73)]:
        g.add_edge(i, j, truth[i].inverse() @ truth[j], INFO, robust=True)
    # A look-alike place: node 58 "seen" 3 m away from where it is.
    bad = g.add_edge(18, 58, truth[18].inverse() @ truth[58] @ Pose2D(3.0, 0.0, 0.0), INFO,
                     robust=True)
    g.optimize(robust=False)
    assert g.outliers(30.0) == [bad]
    g.deactivate(bad)
    g.optimize(robust=False)
    clean = _max_error(g, truth)
    # The robust kernel alone (the edge still active) keeps the damage small.
    g2 = _drifting_graph(truth)
    for i, j in [(0, 40), (5, 45), (12, 52), (25, 65), (33, 73)]:
        g2.add_edge(i, j, truth[i].inverse() @ truth[j], INFO, robust=True)
    g2.optimize(robust=False)
    g2.add_edge(18, 58, truth[18].inverse() @ truth[58] @ Pose2D(3.0, 0.0, 0.0), INFO,
                robust=True)
    g2.optimize()
    assert _max_error(g2, truth) < clean + 0.05


def test_bad_edges_are_refused() -> None:
    g = PoseGraph()
    g.add_node(Pose2D())
    with pytest.raises(ValueError, match="two distinct nodes"):
        g.add_edge(0, 0, Pose2D(), INFO)
    with pytest.raises(ValueError, match="two distinct nodes"):
        g.add_edge(0, 3, Pose2D(), INFO)


def test_frame_helpers() -> None:
    t = Pose2D(1.0, -2.0, 0.7)
    d = np.array([0.01, -0.02, 0.003])
    lhs = t @ Pose2D(*d) @ t.inverse()
    assert np.allclose([lhs.x, lhs.y, lhs.yaw], adjoint(t) @ d, atol=1e-4)
    # Information along the pose's own x axis only, seen from the parent frame.
    yaw = 0.5
    c, s = math.cos(yaw), math.sin(yaw)
    u = np.array([c, s, 0.0])
    parent = np.outer(u, u) * 100.0
    local = to_local_info(parent, yaw)
    assert local[0, 0] == pytest.approx(100.0)
    assert abs(local[1, 1]) < 1e-9


def _keyframes(n: int, step: float = 0.3) -> list[Keyframe]:
    """Keyframes along a straight line every ``step`` m (no scan data: verification only)."""
    empty = np.zeros((0, 2))
    return [Keyframe(Pose2D(k * step, 0.0, 0.0), empty, empty, np.zeros(0, dtype=bool), empty,
                     Pose2D(), k * step, k) for k in range(n)]


def test_a_loop_into_a_new_region_needs_agreeing_hypotheses() -> None:
    kfs = _keyframes(100)
    g = PoseGraph()
    for kf in kfs:
        g.add_node(kf.pose)
    closer = LoopCloser(LoopParams(loop_consistent=2), kfs, g)
    info = np.diag([1e4, 1e4, 1e5])
    # Keyframes 90 and 92 really are 0.5 m off to the side of keyframes 10 and 12.
    h1 = Hypothesis(10, 90, kfs[10].pose.inverse() @ kfs[90].pose @ Pose2D(0.0, 0.5, 0.0),
                    info, 0.8, 0.9)
    h2 = Hypothesis(12, 92, kfs[12].pose.inverse() @ kfs[92].pose @ Pose2D(0.0, 0.5, 0.0),
                    info, 0.8, 0.9)
    # A look-alike disagreeing with both: 1 m along.
    h3 = Hypothesis(11, 94, kfs[11].pose.inverse() @ kfs[94].pose @ Pose2D(1.0, 0.5, 0.0),
                    info, 0.8, 0.9)
    assert closer._verify(h1) == []  # alone: pending
    assert closer._verify(h3) == []  # disagrees with h1: pending too
    added = closer._verify(h2)  # agrees with h1: both accepted
    assert len(added) == 2
    assert {g.jj[e] for e in added} == {90, 92}
    assert closer.new_region
