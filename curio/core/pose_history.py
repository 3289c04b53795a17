"""A short history of timestamped poses: "where was the rover at this stamp?".

Sensor consumers place a measurement with the pose at its stamp, not the newest one: the
costmap puts a scan where the rover was in ``map`` when the scan was taken, the localiser
moves its particles by the odometry between two scans, the mapper pairs a scan with the
odometry of its time. :class:`PoseHistory` keeps the newest ``maxlen`` poses of one frame with
their stamps (clock seconds, oldest first; a stamp older than the newest means time went back,
a reset: the history starts over) and answers in one of three ways:

* ``at(stamp)`` with ``interpolation="linear"``: x, y and the heading (the short way round)
  each interpolated between the two poses around the stamp; a stamp at or after the newest
  gives the newest, one at or before the oldest the oldest;
* ``at(stamp)`` with ``interpolation="se2"``: along the relative motion between the two poses
  around the stamp (``a ∘ (f · (a⁻¹ ∘ b))``, as odometry moves); a stamp after the newest
  gives the newest, one at or before the oldest the oldest;
* ``nearest(stamp)``: the pose whose stamp is nearest (the older of two equally near).

:class:`StampedHistory` is the same without the interpolation, for any stamped item (the mapper
keeps whole odometry messages).

Between two stamps the two interpolations give the same pose up to rounding; on a stamp held
by several poses the linear one takes the last of them, the SE(2) one the first. The costmap
uses ``linear``, the localiser ``se2`` and the mapper ``nearest``, as each did with its own
copy before: their results stay bit-identical.
"""

from __future__ import annotations

import bisect
from typing import Generic, Literal, TypeVar

from curio.core.geometry import Pose2D, wrap_angle

__all__ = ["PoseHistory", "StampedHistory"]

T = TypeVar("T")


class StampedHistory(Generic[T]):
    """The newest items with their stamps, oldest first (see the module docstring).

    Args:
        maxlen: how many items to keep (the oldest go first); None: all.
    """

    def __init__(self, maxlen: int | None) -> None:
        self.maxlen = maxlen
        self._stamps: list[float] = []
        self._items: list[T] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp: float, item: T) -> None:
        """Append the item at ``stamp`` (clock seconds); an older stamp starts over."""
        if self._stamps and stamp < self._stamps[-1]:
            self.clear()
        self._stamps.append(stamp)
        self._items.append(item)
        if self.maxlen is not None and len(self._stamps) > self.maxlen:
            del self._stamps[0], self._items[0]

    def clear(self) -> None:
        """Forget every item."""
        self._stamps.clear()
        self._items.clear()

    def latest(self) -> tuple[float, T] | None:
        """The newest ``(stamp, item)``, or None when empty."""
        if not self._stamps:
            return None
        return self._stamps[-1], self._items[-1]

    def nearest(self, stamp: float) -> T | None:
        """The item whose stamp is nearest ``stamp`` (the older of a tie); None when empty."""
        if not self._stamps:
            return None
        k = min(range(len(self._stamps)), key=lambda i: abs(self._stamps[i] - stamp))
        return self._items[k]


class PoseHistory(StampedHistory[Pose2D]):
    """Timestamped poses of one frame, interpolated (see the module docstring).

    Args:
        maxlen: how many poses to keep (the oldest go first); None: all.
        interpolation: how :meth:`at` interpolates, ``"linear"`` or ``"se2"``.
    """

    def __init__(self, maxlen: int | None,
                 interpolation: Literal["linear", "se2"] = "linear") -> None:
        super().__init__(maxlen)
        self.interpolation = interpolation

    def at(self, stamp: float) -> Pose2D | None:
        """The pose at ``stamp``, interpolated (see the module docstring); None when empty."""
        if not self._stamps:
            return None
        if self.interpolation == "se2":
            return self._se2(stamp)
        return self._linear(stamp)

    def _linear(self, stamp: float) -> Pose2D:
        stamps, poses = self._stamps, self._items
        if stamp >= stamps[-1] or len(stamps) == 1:
            return poses[-1]
        if stamp <= stamps[0]:
            return poses[0]
        i = bisect.bisect_right(stamps, stamp)  # stamps[i - 1] <= stamp < stamps[i]
        t0, p0, t1, p1 = stamps[i - 1], poses[i - 1], stamps[i], poses[i]
        a = 0.0 if t1 == t0 else (stamp - t0) / (t1 - t0)
        return Pose2D(p0.x + a * (p1.x - p0.x), p0.y + a * (p1.y - p0.y),
                      wrap_angle(p0.yaw + a * wrap_angle(p1.yaw - p0.yaw)))

    def _se2(self, stamp: float) -> Pose2D:
        stamps, poses = self._stamps, self._items
        i = bisect.bisect_left(stamps, stamp)  # stamps[i - 1] < stamp <= stamps[i]
        if i <= 0:
            return poses[0]
        if i >= len(stamps):
            return poses[-1]
        a, b = poses[i - 1], poses[i]
        span = stamps[i] - stamps[i - 1]
        f = 0.0 if span <= 0 else (stamp - stamps[i - 1]) / span
        d = a.inverse() @ b
        return a @ Pose2D(d.x * f, d.y * f, d.yaw * f)
