"""Finding the dock in a scan: its shape fitted to the lidar's points.

:class:`DockDetector` takes the scan's points in ``base_link`` and a guess of the dock frame in
``base_link`` (from the map at first, then from the previous fix moved by odometry), keeps the
points near the dock's face, and fits the face's outline (:meth:`DockShape.profile`: two wings
and a V notch) to them by Gauss–Newton on the point-to-segment distances, three parameters (x,
y, heading of the dock frame), dropping points farther than ``OUTLIER_M`` from the outline
after the first iterations. The wings fix the distance and heading, the notch's two sides the
lateral offset. A fix needs enough points on both notch sides and both wings; its residual and
its shift from the guess are reported, and the caller decides whether to trust it (a fix far
from where the map puts the dock is something else).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, wrap_angle

from .station import NOTCH_HALF_M, WING_HALF_M, DockShape

__all__ = ["DockDetector", "DockFix"]

F64 = npt.NDArray[np.float64]

OUTLIER_M = 0.04
MIN_NOTCH_POINTS = 3   # on each side of the notch
MIN_WING_POINTS = 3    # on each wing
ITERATIONS = 12


@dataclass(frozen=True)
class DockFix:
    """A fitted dock.

    Attributes:
        dock_in_base: the dock frame (docked pose) in ``base_link`` at the scan's time.
        rms_m: root-mean-square distance of the inliers to the outline.
        inliers: points used.
        shift_m, shift_rad: how far the fit moved from the guess.
    """

    dock_in_base: Pose2D
    rms_m: float
    inliers: int
    shift_m: float
    shift_rad: float

    def rover_in_dock(self) -> Pose2D:
        """The rover (``base_link``) in the dock frame: (0, 0, 0) is docked."""
        return self.dock_in_base.inverse()


def _closest(points: F64, segs: F64) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """For each point, the closest point on the nearest segment, the unit normal towards the
    point, and the segment's index."""
    a, b = segs[:, 0:2], segs[:, 2:4]
    d = b - a
    ll = (d * d).sum(axis=1)
    rel = points[:, None, :] - a[None, :, :]
    t = np.clip((rel * d[None]).sum(axis=2) / ll[None], 0.0, 1.0)
    q = a[None] + t[..., None] * d[None]
    dist = np.hypot(points[:, None, 0] - q[..., 0], points[:, None, 1] - q[..., 1])
    k = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    closest = q[rows, k]
    seg_dir = d[k] / np.sqrt(ll[k])[:, None]
    normal = np.stack([-seg_dir[:, 1], seg_dir[:, 0]], axis=1)
    return closest, normal, k


class DockDetector:
    """Fits the dock's outline to scan points (see the module docstring).

    Args:
        shape: the dock's geometry.
        window_m: points farther than this from the outline at the guess are ignored.
    """

    def __init__(self, shape: DockShape, window_m: float = 0.35) -> None:
        self.shape = shape
        self.window_m = window_m
        self.profile = shape.profile()

    def _near(self, points_dock: F64) -> F64:
        """Points (dock frame) within the window of the face."""
        f = self.shape.face_x_m
        x, y = points_dock[:, 0], points_dock[:, 1]
        keep = ((x > f - self.window_m) & (x < f + 0.12 + self.window_m)
                & (np.abs(y) < WING_HALF_M + self.window_m))
        return points_dock[keep]

    def detect(self, points_base: F64, guess: Pose2D) -> DockFix | None:
        """The dock's pose in ``base_link`` from scan points ``(N, 2)`` (``base_link``), or
        None when the outline does not fit (too few points on it)."""
        pts = np.asarray(points_base, dtype=np.float64).reshape(-1, 2)
        if len(pts) < 2 * (MIN_NOTCH_POINTS + MIN_WING_POINTS):
            return None
        est = guess
        sel = self._near(est.inverse().transform_points(pts))
        if len(sel) < 2 * (MIN_NOTCH_POINTS + MIN_WING_POINTS):
            return None
        base_pts = est.transform_points(sel)  # the candidate points, base_link
        keep = np.ones(len(base_pts), dtype=bool)
        for it in range(ITERATIONS):
            q = est.inverse().transform_points(base_pts)
            closest, normal, _ = _closest(q, self.profile)
            r = ((q - closest) * normal).sum(axis=1)
            if it >= 2:
                keep = np.abs(r) < OUTLIER_M
            if keep.sum() < 2 * (MIN_NOTCH_POINTS + MIN_WING_POINTS):
                return None
            qk, nk, rk = q[keep], normal[keep], r[keep]
            # r(δ) for the dock frame moved by δ = (dx, dy, dθ) (small): q' = δ⁻¹ q.
            jac = np.stack([-nk[:, 0], -nk[:, 1], nk[:, 0] * qk[:, 1] - nk[:, 1] * qk[:, 0]],
                           axis=1)
            try:
                delta, *_ = np.linalg.lstsq(jac, -rk, rcond=None)
            except np.linalg.LinAlgError:
                return None
            est = est @ Pose2D(float(delta[0]), float(delta[1]), float(delta[2]))
            if float(np.abs(delta).max()) < 1e-5:
                break
        return self._fix(est, guess, base_pts)

    def _fix(self, est: Pose2D, guess: Pose2D, base_pts: F64) -> DockFix | None:
        q = est.inverse().transform_points(base_pts)
        closest, normal, seg = _closest(q, self.profile)
        r = ((q - closest) * normal).sum(axis=1)
        inl = np.abs(r) < OUTLIER_M
        counts = np.bincount(seg[inl], minlength=4)
        # Wing points must lie beyond the notch's edges, notch points inside them.
        if counts[1] < MIN_NOTCH_POINTS or counts[2] < MIN_NOTCH_POINTS or \
                counts[0] < MIN_WING_POINTS or counts[3] < MIN_WING_POINTS:
            return None
        if not (np.abs(q[inl & ((seg == 1) | (seg == 2)), 1]) <= NOTCH_HALF_M + 0.01).all():
            return None
        rms = float(np.sqrt(np.mean(r[inl] ** 2)))
        return DockFix(est, rms, int(inl.sum()), est.distance_to(guess),
                       abs(wrap_angle(est.yaw - guess.yaw)))


def heading_error_deg(rover_in_dock: Pose2D) -> float:
    """The rover's heading off the dock's axis, degrees."""
    return math.degrees(wrap_angle(rover_in_dock.yaw))
