"""The pose gate: a fresh pose from a working localisation, or hold, then give up."""

from __future__ import annotations

from curio.core.geometry import Pose2D
from curio.core.messages import LocalizationStatus, PoseWithCovariance
from curio.nav.api import LocalizationLostError
from curio.nav.navigator.pose_gate import PoseGate

P = Pose2D(1.0, 2.0, 0.5)


def pose(stamp: float) -> PoseWithCovariance:
    return PoseWithCovariance(stamp, P)


def loc(state: str) -> LocalizationStatus:
    return LocalizationStatus(0.0, state)  # type: ignore[arg-type]


def test_a_fresh_pose_passes() -> None:
    gate = PoseGate(10.0)
    assert gate.check(pose(5.0), None, 5.0).pose == P
    assert gate.check(pose(5.0), loc("ok"), 6.0).pose == P  # 1 s old: still fresh
    assert gate.check(pose(5.0), loc("uncertain"), 5.5).pose == P


def test_a_pose_older_than_1_s_is_no_pose() -> None:
    v = PoseGate(10.0).check(pose(5.0), None, 6.01)
    assert v.pose is None and v.error is None and not v.newly_lost and v.reason == "no pose"


def test_no_pose_holds_for_lost_timeout_s_then_aborts() -> None:
    gate = PoseGate(4.0)
    assert gate.check(None, None, 10.0).error is None  # the hold begins
    assert gate.check(None, None, 14.0).error is None  # 4 s: still held
    v = gate.check(None, None, 14.1)
    assert isinstance(v.error, LocalizationLostError)
    assert str(v.error) == ("no pose in map for 4 s (nav.controller.lost_timeout_s): "
                            "localisation is not running")


def test_a_pose_in_between_starts_the_hold_afresh() -> None:
    gate = PoseGate(4.0)
    gate.check(None, None, 10.0)
    assert gate.check(pose(13.0), None, 13.0).pose == P
    assert gate.check(None, None, 14.5).error is None  # counted from 14.5, not 10
    assert gate.check(None, None, 18.6).error is not None


def test_lost_localisation_holds_says_so_once_then_aborts() -> None:
    gate = PoseGate(10.0)
    first = gate.check(pose(1.0), loc("lost"), 1.0)
    assert first.pose is None and first.newly_lost and first.reason == "lost"
    later = gate.check(pose(5.0), loc("lost"), 5.0)
    assert later.pose is None and not later.newly_lost and later.error is None
    assert gate.check(pose(11.0), loc("lost"), 11.0).error is None
    v = gate.check(pose(11.1), loc("lost"), 11.1)
    assert isinstance(v.error, LocalizationLostError)
    assert str(v.error) == ("localisation lost for 10 s (nav.controller.lost_timeout_s): "
                            "set the pose on the dashboard")


def test_found_again_the_next_loss_is_new() -> None:
    gate = PoseGate(10.0)
    gate.check(pose(1.0), loc("lost"), 1.0)
    assert gate.check(pose(2.0), loc("ok"), 2.0).pose == P
    again = gate.check(pose(3.0), loc("lost"), 3.0)
    assert again.newly_lost
    assert gate.check(pose(12.5), loc("lost"), 12.5).error is None  # from 3 s, not 1 s


def test_reset_forgets_a_hold() -> None:
    gate = PoseGate(4.0)
    gate.check(None, None, 0.0)
    gate.check(pose(1.0), loc("lost"), 1.0)
    gate.reset()
    assert gate.check(pose(10.0), loc("lost"), 10.0).newly_lost
    assert gate.check(None, None, 11.0).error is None
