"""Localisation in a known map: an adaptive (KLD) particle filter with scan-matching refinement.

AMCL-class, vectorised over particles × beams:

* **Motion model:** the odometry ("diff") model of Probabilistic Robotics — each update splits the
  odometry increment into rotation, translation, rotation and perturbs each with noise scaled by
  ``odom_alpha1..4``.
* **Sensor model:** the likelihood field — beam end points looked up in a precomputed Euclidean
  distance field of the occupied cells (``curio.core.distance``, SciPy's EDT), a Gaussian of
  ``laser_sigma_hit_m`` mixed with a uniform ``laser_z_rand``.
* **Adaptive particle count** by KLD sampling (``kld_err``, ``kld_z``; bins 0.25 m × 0.25 m ×
  10°), between ``min_particles`` and ``max_particles``.
* **Recovery:** random particles are injected when the short-term fit average ``w_fast`` drops
  below the long-term ``w_slow`` (``recovery_alpha_fast`` / ``recovery_alpha_slow``); when the
  fit stays poor the rover is declared ``lost`` and (``auto_relocalize``) a global search runs:
  every free position on a ``global_step_m`` lattice × ``global_yaw_step_rad`` headings is scored
  against the scan (spread over several scans so no update blocks the loop for long), the best
  candidates are refined by scan matching and seed the particle set.
* **Scan matching:** the best cluster's mean pose is refined by a few Gauss–Newton iterations on
  the bilinearly interpolated distance field (the wall face, half a cell from the occupied cell
  centres, is the zero level); the cluster is shifted by the correction. This gives
  centimetre-level tracking where a pure particle filter is limited by its sample spacing.

Frames (REP-105): particles and the published ``POSE`` are ``base_link`` in ``map``; the
correction ``MAP_TO_ODOM`` is ``odom`` in ``map``; odometry is ``base_link`` in ``odom``; scans are
in ``laser`` (``robot.laser_pose`` in ``base_link``). Angles in radians, distances in metres.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal, Protocol

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import LocalizationConfig
from curio.core.distance import distance_to_features
from curio.core.geometry import Pose2D, wrap_angle, wrap_angles
from curio.core.messages import (
    DriverHealth,
    LaserScan,
    LocalizationStatus,
    Odometry,
    PoseWithCovariance,
)
from curio.core.pose_history import PoseHistory
from curio.core.topics import HEALTH, INITIAL_POSE, LOCALIZATION, ODOM, SCAN
from curio.estimation.correction import MapOdomPublisher
from curio.estimation.localization_kernels import (
    beam_evidence,
    ends_local,
    heaviest_bin,
    lookup_grad_points,
    lookup_points,
    lookup_poses,
    match_terms,
)
from curio.estimation.maps import OccupancyGrid

__all__ = [
    "BeamFilter",
    "DistanceField",
    "Localizer",
    "LocalizerNode",
    "MatchResult",
    "scan_match",
]

log = logging.getLogger("curio.estimation.localization")

F64 = npt.NDArray[np.float64]
State = Literal["ok", "uncertain", "lost", "off"]

# Pose-beam pairs the likelihood is computed for at once (a 512 KiB buffer; see ``_loglik``).
LOGLIK_BLOCK_VALUES = 1 << 16
# A beam that stops in front of the map counts this much of one on a wall in the fit
# (``Localizer._fit``).
IN_FRONT_WEIGHT = 0.5
# Beams in front of the map are left out of the particles' weights only if at least this
# share of a scan's beams, and this many, remain (``Localizer._without_unmapped``).
MIN_EVIDENCE_SHARE = 0.2
MIN_EVIDENCE_BEAMS = 8
# What a beam end says about a pose (``beam_evidence``'s codes).
AGAINST, ON_WALL, IN_FRONT = 0, 1, 2
# Ends in front of the map on one straight surface (within the tolerance) wider than this are
# a wall seen from a wrong pose, not people (``Localizer._wide_in_front_against``), when they
# are at least MIN_WALL_BEAMS; neighbours within the gap (or four beam spacings at their range,
# at most MAX_JOIN_GAP_M) are on one surface, metres.
MAX_UNMAPPED_WIDTH_M = 0.8
JOIN_GAP_M = 0.3
MAX_JOIN_GAP_M = 0.6
STRAIGHT_TOLERANCE_M = 0.05
MIN_WALL_BEAMS = 4
# Beams whose ends lie this far in front of the map (or twice the position spread) do not
# weigh the particles (``Localizer._without_unmapped``), metres.
UNMAPPED_MARGIN_M = 0.3


def _flat(a: F64) -> F64:
    """``a`` as a contiguous 1-D float64 array (a view when it already is one)."""
    return np.ascontiguousarray(a, dtype=np.float64).reshape(-1)


class DistanceField:
    """Distance (metres) from every cell centre to the nearest occupied cell centre.

    Lookups take points in ``map``; points outside the grid read ``max_dist_m``. On an
    unrotated grid (every map Curio builds) they run compiled
    (:mod:`curio.estimation.localization_kernels`, the same arithmetic); a rotated origin takes
    the numpy path.
    """

    def __init__(self, grid: OccupancyGrid, max_dist_m: float = 2.0) -> None:
        self.resolution_m = grid.resolution_m
        self.origin = grid.origin
        self.max_dist_m = max_dist_m
        occ = grid.occupied_mask()
        if occ.any():
            dist = distance_to_features(occ) * grid.resolution_m
        else:
            dist = np.full(occ.shape, max_dist_m)
        self.dist_m: F64 = np.minimum(np.asarray(dist, dtype=np.float64), max_dist_m)
        self.height, self.width = self.dist_m.shape
        self._flat = self.dist_m.ravel()
        self._inv = grid.origin.inverse()
        self._rotated = abs(grid.origin.yaw) > 1e-12

    def to_local(self, x: F64, y: F64) -> tuple[F64, F64]:
        """Map coordinates → grid-local metres (origin corner at (0, 0))."""
        if not self._rotated:
            return x - self.origin.x, y - self.origin.y
        c, s = math.cos(self._inv.yaw), math.sin(self._inv.yaw)
        return (self._inv.x + c * x - s * y, self._inv.y + s * x + c * y)

    def lookup(self, x: F64, y: F64) -> F64:
        """Nearest-cell distance at map points (any shape), metres."""
        if not self._rotated:
            out = np.empty(np.shape(x))
            lookup_points(self.dist_m, self.origin.x, self.origin.y, self.resolution_m,
                          self.max_dist_m, _flat(x), _flat(y), out.reshape(-1))
            return out
        lx, ly = self.to_local(x, y)
        col = np.floor(lx / self.resolution_m).astype(np.int64)
        row = np.floor(ly / self.resolution_m).astype(np.int64)
        inside = (row >= 0) & (row < self.height) & (col >= 0) & (col < self.width)
        idx = np.where(inside, row * self.width + col, 0)
        return np.where(inside, self._flat[idx], self.max_dist_m)

    def lookup_poses(self, poses: F64, pts: F64, out: F64 | None = None) -> F64:
        """Nearest-cell distance ``(M, N)`` at the points ``pts`` ``(N, 2)`` (``base_link``)
        seen from each of the poses ``poses`` ``(M, 3)`` (x, y, yaw in ``map``), metres;
        written into ``out`` (a C-contiguous ``(M, N)`` array) when given."""
        c = np.cos(poses[:, 2])
        s = np.sin(poses[:, 2])
        if self._rotated:
            wx = poses[:, 0:1] + c[:, None] * pts[None, :, 0] - s[:, None] * pts[None, :, 1]
            wy = poses[:, 1:2] + s[:, None] * pts[None, :, 0] + c[:, None] * pts[None, :, 1]
            if out is None:
                return self.lookup(wx, wy)
            out[...] = self.lookup(wx, wy)
            return out
        if out is None:
            out = np.empty((len(poses), len(pts)))
        lookup_poses(self.dist_m, self.origin.x, self.origin.y, self.resolution_m,
                     self.max_dist_m, _flat(poses[:, 0]), _flat(poses[:, 1]), c, s,
                     _flat(pts[:, 0]), _flat(pts[:, 1]), out)
        return out

    def lookup_grad(self, x: F64, y: F64) -> tuple[F64, F64, F64]:
        """Bilinear distance and its gradient (d/dx, d/dy in ``map``) at map points."""
        if not self._rotated:
            shape = np.shape(x)
            val, gx, gy = np.empty(shape), np.empty(shape), np.empty(shape)
            lookup_grad_points(self.dist_m, self.origin.x, self.origin.y, self.resolution_m,
                               self.max_dist_m, _flat(x), _flat(y), val.reshape(-1),
                               gx.reshape(-1), gy.reshape(-1))
            return val, gx, gy
        lx, ly = self.to_local(x, y)
        res = self.resolution_m
        fx = lx / res - 0.5
        fy = ly / res - 0.5
        c0 = np.floor(fx).astype(np.int64)
        r0 = np.floor(fy).astype(np.int64)
        tx = fx - c0
        ty = fy - r0
        inside = (r0 >= 0) & (r0 < self.height - 1) & (c0 >= 0) & (c0 < self.width - 1)
        r0c = np.where(inside, r0, 0)
        c0c = np.where(inside, c0, 0)
        d = self.dist_m
        d00 = d[r0c, c0c]
        d01 = d[r0c, c0c + 1]
        d10 = d[r0c + 1, c0c]
        d11 = d[r0c + 1, c0c + 1]
        val = (d00 * (1 - tx) * (1 - ty) + d01 * tx * (1 - ty) + d10 * (1 - tx) * ty
               + d11 * tx * ty)
        gx = ((d01 - d00) * (1 - ty) + (d11 - d10) * ty) / res
        gy = ((d10 - d00) * (1 - tx) + (d11 - d01) * tx) / res
        val = np.where(inside, val, self.max_dist_m)
        gx = np.where(inside, gx, 0.0)
        gy = np.where(inside, gy, 0.0)
        if self._rotated:
            c, s = math.cos(self.origin.yaw), math.sin(self.origin.yaw)
            gx, gy = c * gx - s * gy, s * gx + c * gy
        return val, gx, gy


def _distinct_hypotheses(ranked: list[tuple[float, Pose2D]], max_count: int = 8
                         ) -> list[tuple[float, Pose2D]]:
    """The candidates ``(fine fit, pose)`` (best first) that fit within 0.05 of the best, at most
    ``max_count``, none within 0.3 m and 0.3 rad of a better one."""
    good = [r for r in ranked if r[0] >= ranked[0][0] - 0.05] if ranked else []
    hyps: list[tuple[float, Pose2D]] = []
    for frac, pose in good:
        if all(pose.distance_to(h[1]) > 0.3
               or abs(wrap_angle(pose.yaw - h[1].yaw)) > 0.3 for h in hyps):
            hyps.append((frac, pose))
        if len(hyps) >= max_count:
            break
    return hyps


@dataclass(frozen=True, slots=True)
class MatchResult:
    """Outcome of :func:`scan_match`.

    Attributes:
        pose: the refined pose in ``map``.
        inlier_fraction: share of points within the inlier distance of a wall face.
        rms_m: RMS residual of the inliers, metres.
        covariance: 3×3 covariance (x, y, yaw) from the Gauss–Newton normal matrix.
        converged: whether the last step was below 1 mm / 0.5 mrad.
    """

    pose: Pose2D
    inlier_fraction: float
    rms_m: float
    covariance: F64
    converged: bool


HUBER_M = 0.05  # scan match: residuals beyond this weigh HUBER_M / |r|
# Constant matrices, made once (read-only): the scan match's damping of the normal matrix, and
# the floor added to the filter's covariance (1 cm, 0.3°; x m², y m², yaw rad²).
_GN_DAMPING: F64 = np.diag([1e-4, 1e-4, 1e-3])
_GN_DAMPING.flags.writeable = False
_COV_FLOOR: F64 = np.diag([1e-4, 1e-4, 3e-5])
_COV_FLOOR.flags.writeable = False


class _MatchTerms:
    """The per-point terms of one scan-match iteration: residuals ``r`` of the used points
    (``|r| < max_residual_m``), their Jacobian rows ``j`` (x, y, yaw) and the Huber-weighted
    rows ``jw``; None when fewer than 6 points are used."""

    def __init__(self, field: DistanceField, px: F64, py: F64, half: float,
                 max_residual_m: float) -> None:
        self.field = field
        self.px, self.py = _flat(px), _flat(py)
        self.half = half
        self.max_residual_m = max_residual_m
        n = len(self.px)
        self._r = np.empty(n)
        self._j = np.empty((n, 3))
        self._jw = np.empty((n, 3))

    def at(self, x: float, y: float, c: float, s: float) -> tuple[F64, F64, F64] | None:
        """The terms at pose ``(x, y)`` with heading cosine ``c`` and sine ``s``."""
        f = self.field
        if f._rotated:
            return self._numpy(x, y, c, s)
        k = match_terms(f.dist_m, f.origin.x, f.origin.y, f.resolution_m, f.max_dist_m, x, y,
                        c, s, self.px, self.py, self.half, self.max_residual_m, HUBER_M,
                        self._r, self._j, self._jw)
        if k < 6:
            return None
        return self._r[:k], self._j[:k], self._jw[:k]

    def _numpy(self, x: float, y: float, c: float, s: float) -> tuple[F64, F64, F64] | None:
        px, py = self.px, self.py
        d, gx, gy = self.field.lookup_grad(x + c * px - s * py, y + s * px + c * py)
        r = d - self.half
        use = np.abs(r) < self.max_residual_m
        if np.count_nonzero(use) < 6:
            return None
        r = r[use]
        jx = gx[use]
        jy = gy[use]
        jt = jx * (-s * px[use] - c * py[use]) + jy * (c * px[use] - s * py[use])
        j = np.stack([jx, jy, jt], axis=1)
        w = np.where(np.abs(r) <= HUBER_M, 1.0, HUBER_M / np.maximum(np.abs(r), 1e-12))
        return r, j, j * w[:, None]


def scan_match(field: DistanceField, points: F64, guess: Pose2D, *, iterations: int = 8,
               max_residual_m: float = 0.15, inlier_m: float = 0.1,
               sigma_m: float = 0.03, surface_offset_m: float | None = None,
               prior_cov: F64 | None = None, prior_mean: Pose2D | None = None) -> MatchResult:
    """Refine ``guess`` so that ``points`` (``base_link``) fall on wall faces (Gauss–Newton).

    The residual of a point is its interpolated distance to the nearest occupied cell centre
    minus ``surface_offset_m`` (default half a cell: the face of a wall drawn as cells; 0 for
    maps built from scan end points); points further than ``max_residual_m`` from a face are
    ignored (unmapped obstacles, glass, people), the rest are Huber-weighted.

    ``prior_cov`` (3×3, x m, y m, yaw rad, in ``map``) makes ``guess`` a Gaussian prior: the
    result is the maximum a posteriori pose, so directions the scan does not constrain (one wall,
    one distant shape in an open area) stay where the prior puts them instead of sliding, and
    the returned covariance is the posterior one. The prior is centred on ``prior_mean``
    (default ``guess``, where the iterations start).
    """
    centre = guess if prior_mean is None else prior_mean
    half = 0.5 * field.resolution_m if surface_offset_m is None else surface_offset_m
    x, y, th = guess.x, guess.y, guess.yaw
    px, py = points[:, 0], points[:, 1]
    converged = False
    prior_info: F64 | None = None
    if prior_cov is not None:  # in units of the point residuals (m²)
        prior_info = np.asarray(np.linalg.inv(prior_cov) * sigma_m**2, dtype=np.float64)
    h = np.eye(3) * 1e-6 if prior_info is None else prior_info.copy()
    terms = _MatchTerms(field, px, py, half, max_residual_m)
    for _ in range(iterations):
        c, s = math.cos(th), math.sin(th)
        got = terms.at(x, y, c, s)
        if got is None:
            break
        r, j, jw = got
        h = jw.T @ j + _GN_DAMPING
        g = jw.T @ r
        if prior_info is not None:
            dev = np.array([x - centre.x, y - centre.y, wrap_angle(th - centre.yaw)])
            h = h + prior_info
            g = g + prior_info @ dev
        try:
            step = -np.linalg.solve(h, g)
        except np.linalg.LinAlgError:
            break
        # Clipped to ±0.1 as np.clip does (min of max, a NaN kept), on Python floats.
        sx = min(max(float(step[0]), -0.1), 0.1)
        sy = min(max(float(step[1]), -0.1), 0.1)
        st = min(max(float(step[2]), -0.1), 0.1)
        x += sx
        y += sy
        th = wrap_angle(th + st)
        if abs(sx) < 1e-3 and abs(sy) < 1e-3 and abs(st) < 5e-4:
            converged = True
            break
    c, s = math.cos(th), math.sin(th)
    wx = x + c * px - s * py
    wy = y + s * px + c * py
    d = field.lookup(wx, wy)
    inl = np.abs(d - half) <= max(inlier_m, half)
    frac = float(np.count_nonzero(inl)) / max(1, len(px))
    dd, _, _ = field.lookup_grad(wx[inl], wy[inl])
    rms = float(np.sqrt(np.mean((dd - half) ** 2))) if np.any(inl) else float("inf")
    try:
        cov = np.linalg.inv(h) * sigma_m**2
    except np.linalg.LinAlgError:
        cov = np.eye(3)
    return MatchResult(Pose2D(x, y, th), frac, rms, np.asarray(cov, dtype=np.float64), converged)


def _kld_bound(k: F64, err: float, z: float) -> F64:
    """KLD sample count for ``k`` occupied bins (Fox 2003), vectorised."""
    k1 = np.maximum(k - 1.0, 1.0)
    a = 2.0 / (9.0 * k1)
    out: F64 = (k1 / (2.0 * err)) * (1.0 - a + np.sqrt(a) * z) ** 3
    return np.where(k <= 1, 1.0, out)


@dataclass
class _GlobalSearch:
    """State of a global search spread over several scans.

    The candidates are every lattice position at every heading, ``M = len(xy) * len(yaws)``,
    visited in the random ``order``: candidate ``k`` is at ``xy[k // len(yaws)]`` heading
    ``yaws[k % len(yaws)]``. Only the chunk a scan scores is made (:meth:`chunk`): the whole
    list (195 878 candidates, 4.7 MB in the default building) was made and copied shuffled at
    every kidnap.
    """

    xy: F64  # (K, 2) lattice positions in map
    yaws: F64  # (Y,) headings, rad
    order: npt.NDArray[np.int32]  # (M,) a permutation of the candidates' indices
    recheck: bool = False  # started by a long middling fit, not by being lost
    next_index: int = 0
    top: F64 | None = None  # (K, 4): x, y, yaw, score — in map at ``top_odom``
    top_odom: Pose2D | None = None

    def __len__(self) -> int:
        return len(self.order)

    def chunk(self, start: int, end: int) -> F64:
        """Candidates ``order[start:end]`` as ``(n, 3)`` poses (x, y, yaw in ``map``)."""
        idx = self.order[start:end]
        cell, heading = np.divmod(idx, len(self.yaws))
        poses = np.empty((len(idx), 3))
        poses[:, 0] = self.xy[cell, 0]
        poses[:, 1] = self.xy[cell, 1]
        poses[:, 2] = self.yaws[heading]
        return poses


class Localizer:
    """The particle filter, free of any bus or clock (the node below feeds it).

    Call :meth:`initialize` (or :meth:`global_localization`), then :meth:`update` with each scan
    and the odometry pose (``base_link`` in ``odom``) at the scan's time.
    """

    def __init__(self, grid: OccupancyGrid, cfg: LocalizationConfig,
                 laser_pose: Pose2D = Pose2D(), seed: int = 0) -> None:
        self.cfg = cfg
        self.grid = grid
        self.laser_pose = laser_pose
        self.rng = np.random.default_rng(seed)
        self.field = DistanceField(grid, cfg.laser_likelihood_max_dist_m)
        free = grid.free_mask() & (self.field.dist_m >= 0.15)
        rows, cols = np.nonzero(free)
        if len(rows) == 0:
            rows, cols = np.nonzero(grid.free_mask())
        self._free_rc = np.stack([rows, cols], axis=1)
        self._free_cells = np.ascontiguousarray(grid.free_mask())
        self.particles: F64 = np.zeros((0, 3))
        self.weights: F64 = np.zeros(0)
        self.w_slow = 0.0
        self.w_fast = 0.0
        self._last_odom: Pose2D | None = None
        self.pose = Pose2D()
        self.covariance: F64 = np.diag([0.25, 0.25, 0.07])
        self.inlier_fraction = 1.0
        self.poor_scans = 0
        self.mediocre_scans = 0
        self.state: State = "uncertain"
        self.updates = 0
        self.search: _GlobalSearch | None = None
        self.searches = 0  # global searches started (diagnostics)
        self.since_set_m = math.inf  # distance driven since a pose was set from outside
        self.ok_since_set = True  # the filter was ``ok`` since a pose was set from outside
        self.initialized = False
        # The particles agree on one place (the last estimate's cluster holds 0.8 of the
        # weight; a set pose): only then is a beam in front of the map at the estimate
        # dropped (``_without_unmapped``) — among hypotheses it would favour the first.
        self.unimodal = False
        # Tracking prior: the last estimate moved by odometry, with its covariance (map frame).
        self._delta = Pose2D()
        self.track_cov: F64 | None = None
        self._stationary_due_s = -math.inf  # scan time of the next check while standing still
        self._loglik_buf: F64 = np.empty(0)  # :meth:`_loglik`'s working block

    # --- initialisation --------------------------------------------------------------------
    def initialize(self, pose: Pose2D, std_xy_m: float | None = None,
                   std_yaw_rad: float | None = None) -> None:
        """Spread the particles as a Gaussian around ``pose`` (``map``)."""
        sxy = self.cfg.initial_std_xy_m if std_xy_m is None else std_xy_m
        syaw = self.cfg.initial_std_yaw_rad if std_yaw_rad is None else std_yaw_rad
        n = max(self.cfg.min_particles, min(self.cfg.max_particles, 1000))
        p = np.empty((n, 3))
        p[:, 0] = pose.x + self.rng.normal(0.0, sxy, n)
        p[:, 1] = pose.y + self.rng.normal(0.0, sxy, n)
        p[:, 2] = wrap_angles(pose.yaw + self.rng.normal(0.0, syaw, n))
        p[0] = pose.as_tuple()
        self.particles = p
        self.weights = np.full(n, 1.0 / n)
        self.pose = pose
        self.covariance = np.diag([sxy**2, sxy**2, syaw**2])
        self.search = None
        self.poor_scans = 0
        self.mediocre_scans = 0
        self.since_set_m = 0.0  # a pose set from outside: no re-check until driven a while
        self.ok_since_set = False
        self.w_slow = self.w_fast = 0.0
        self.state = "uncertain"
        self._force_update = True
        self._last_odom = None  # the motion before this call is already in ``pose``
        self.track_cov = None
        self.unimodal = True
        self.initialized = True

    def global_localization(self) -> None:
        """Forget the pose: particles spread over the free space and a global search starts."""
        n = self.cfg.max_particles
        self.particles = self._random_poses(n)
        self.weights = np.full(n, 1.0 / n)
        self.state = "lost"
        self.poor_scans = self.cfg.lost_after_scans
        self.covariance = np.diag([100.0, 100.0, math.pi**2])
        self.track_cov = None
        self.unimodal = False
        self._start_search()
        self._force_update = True
        self.initialized = True

    def _random_poses(self, n: int) -> F64:
        pick = self.rng.integers(0, len(self._free_rc), n)
        rc = self._free_rc[pick].astype(np.float64)
        res = self.grid.resolution_m
        local = (rc[:, ::-1] + self.rng.random((n, 2))) * res
        xy = self.grid.origin.transform_points(local)
        yaw = self.rng.uniform(-math.pi, math.pi, n)
        return np.column_stack([xy, yaw])

    # --- the filter --------------------------------------------------------------------------
    def update(self, scan: LaserScan, odom_pose: Pose2D) -> bool:
        """Process one scan taken at odometry pose ``odom_pose``; return whether it updated."""
        if not self.initialized:
            return False
        if self._last_odom is None:
            self._last_odom = odom_pose
            self._force_update = True
        delta = self._last_odom.inverse() @ odom_pose
        moved = (math.hypot(delta.x, delta.y) >= self.cfg.update_min_d_m
                 or abs(delta.yaw) >= self.cfg.update_min_a_rad)
        searching = self.search is not None
        if not (moved or self._force_update or searching or self._stationary_misfit(scan)):
            return False
        self._force_update = False
        self._last_odom = odom_pose
        self._delta = delta
        self.since_set_m += math.hypot(delta.x, delta.y)
        self._motion_update(delta)
        if self.search is not None:
            self.search.top_odom = (self.search.top_odom @ delta
                                    if self.search.top_odom is not None else None)
            self._propagate_top(delta)
        pts_pf = scan.points(self.laser_pose, max_beams=self.cfg.laser_beams,
                             range_max_m=scan.range_max_m - 0.05)
        if self.search is None and self.state != "lost" and self.unimodal and len(pts_pf) >= 8:
            pts_pf = self._without_unmapped(pts_pf, self.pose @ delta)
        if len(pts_pf) < 8:
            # Nothing to weigh the particles with: the estimate follows the odometry.
            track = self._predict_track()
            if track is not None:
                self.pose, self.track_cov = track
                self._delta = Pose2D()
            return False
        self._sensor_update(pts_pf)
        self._estimate(scan)
        if self.search is not None:
            self._search_step(scan, pts_pf)
        self._resample()
        self.updates += 1
        return True

    def _stationary_misfit(self, scan: LaserScan) -> bool:
        """Standing still: whether this scan (every ``stationary_check_s`` of scan time) fits
        the map so poorly at the estimate that the filter must update.

        The filter does not update without motion (repeating one view would make it
        overconfident), so a rover lifted and put down elsewhere while parked kept its old pose
        and ``ok``. A poor fit now updates the filter, scan after scan, which counts the poor
        scans as driving does (``lost`` after ``lost_after_scans``); a good one ends the count.
        A middling fit (below ``ok_inlier_fraction``), or a filter its last update left unsure
        (``uncertain``), is counted check by check as the updates count a middling fit while
        driving, and ``recheck_after_scans`` of them in a row start the whole-map re-check: a
        rover carried to a place whose scan fits its old pose well enough stayed ``uncertain``
        there for good (never ``lost``, no search, no help).
        """
        if scan.stamp < self._stationary_due_s:
            return False
        self._stationary_due_s = scan.stamp + self.cfg.stationary_check_s
        pts = scan.points(self.laser_pose, max_beams=self.cfg.laser_beams,
                          range_max_m=scan.range_max_m - 0.05)
        if len(pts) < 8:
            return False
        fit = self._fit(pts, self.pose)
        if fit >= self.cfg.lost_inlier_fraction:
            self.poor_scans = 0
            if fit >= self.cfg.ok_inlier_fraction and self.state == "ok":
                self.mediocre_scans = 0
                return False
            # Standing still the filter does not settle by itself: count, then check the map.
            # The guard after a set pose (recheck_after_set_m) does not hold a parked rover
            # that was ``ok`` since: the map fitted where it was set, and a middling fit now,
            # without a wheel turned, means it was carried (the soak's parked kidnaps).
            self.mediocre_scans += 1
            if self._recheck_due(parked=True):
                self._start_search(recheck=True)
                return True  # the search runs in the updates, scan after scan
            return False
        self._stationary_due_s = -math.inf  # poor: update with every scan until it fits
        return True

    def _motion_update(self, delta: Pose2D) -> None:
        """Odometry model (diff): rot1, trans, rot2 with noise; ``delta`` in the old base frame."""
        trans = math.hypot(delta.x, delta.y)
        rot1 = math.atan2(delta.y, delta.x) if trans > 0.01 else 0.0
        rot2 = wrap_angle(delta.yaw - rot1)
        # Backward motion: the noise should scale with the smaller of rot1 and rot1 - π.
        r1n = min(abs(wrap_angle(rot1)), abs(wrap_angle(rot1 - math.pi)))
        r2n = min(abs(wrap_angle(rot2)), abs(wrap_angle(rot2 - math.pi)))
        a1, a2, a3, a4 = (self.cfg.odom_alpha1, self.cfg.odom_alpha2, self.cfg.odom_alpha3,
                          self.cfg.odom_alpha4)
        n = len(self.particles)
        s1 = math.sqrt(a1 * r1n**2 + a2 * trans**2)
        st = math.sqrt(a3 * trans**2 + a4 * (r1n**2 + r2n**2))
        s2 = math.sqrt(a1 * r2n**2 + a2 * trans**2)
        h1 = rot1 - self.rng.normal(0.0, 1.0, n) * s1
        ht = trans - self.rng.normal(0.0, 1.0, n) * st
        h2 = rot2 - self.rng.normal(0.0, 1.0, n) * s2
        p = self.particles
        th = p[:, 2] + h1
        p[:, 0] += ht * np.cos(th)
        p[:, 1] += ht * np.sin(th)
        p[:, 2] = wrap_angles(th + h2)

    def _loglik(self, poses: F64, pts: F64, sigma_m: float) -> F64:
        """Per-pose mean log-likelihood per beam (likelihood field), shape ``(M,)``.

        Computed in blocks of at most ``LOGLIK_BLOCK_VALUES`` pose-beam pairs in one buffer
        kept by the localiser, in place: a global search scores 20 000 poses a scan, whose
        ``(M, N)`` temporaries were six arrays of 6 MB each. The same operations in the same
        order: the results are identical to the last bit.
        """
        m, n = len(poses), len(pts)
        out: F64 = np.empty(m)
        if m == 0:
            return out
        half = 0.5 * self.grid.resolution_m
        z_rand = self.cfg.laser_z_rand / self.cfg.laser_likelihood_max_dist_m
        z_hit = self.cfg.laser_z_hit
        rows = max(1, LOGLIK_BLOCK_VALUES // max(1, n))
        if len(self._loglik_buf) < min(m, rows) * n:
            self._loglik_buf = np.empty(max(LOGLIK_BLOCK_VALUES, n))
        for a in range(0, m, rows):
            b = min(m, a + rows)
            d = self._loglik_buf[:(b - a) * n].reshape(b - a, n)
            self.field.lookup_poses(poses[a:b], pts, out=d)
            d -= half
            d /= sigma_m
            np.square(d, out=d)
            d *= -0.5
            np.exp(d, out=d)
            d *= z_hit
            d += z_rand
            np.log(d, out=d)
            np.mean(d, axis=1, out=out[a:b])
        return out

    def _sensor_update(self, pts: F64) -> None:
        ll = self._loglik(self.particles, pts, self.cfg.laser_sigma_hit_m)
        # Beams are not independent: temper the joint likelihood (sqrt of the beam count).
        total = ll * math.sqrt(len(pts))
        w = self.weights * np.exp(total - total.max())
        s = w.sum()
        self.weights = w / s if s > 0 and np.isfinite(s) else np.full(len(w), 1.0 / len(w))
        w_avg = float(np.mean(np.exp(ll)))
        if self.w_slow == 0.0:
            self.w_slow = self.w_fast = w_avg
        else:
            self.w_slow += self.cfg.recovery_alpha_slow * (w_avg - self.w_slow)
            self.w_fast += self.cfg.recovery_alpha_fast * (w_avg - self.w_fast)

    def _bins(self, p: F64) -> npt.NDArray[np.int64]:
        bx = np.floor(p[:, 0] / 0.25).astype(np.int64)
        by = np.floor(p[:, 1] / 0.25).astype(np.int64)
        bt = np.floor((p[:, 2] + math.pi) / math.radians(10.0)).astype(np.int64)
        return (bx * 100_003 + by) * 64 + bt

    def _cluster(self) -> npt.NDArray[np.bool_]:
        """Particles near the heaviest 0.5 m bin: the best hypothesis."""
        p = self.particles
        sel = np.empty(len(p), dtype=np.bool_)
        heaviest_bin(np.ascontiguousarray(p), np.ascontiguousarray(self.weights), 0.5, sel)
        w = self.weights[sel]
        scl = w.sum()  # np.average's arithmetic, without its checks and dispatch
        if scl == 0.0:
            raise ZeroDivisionError("Weights sum to zero, can't be normalized")
        cx = float((p[sel, 0] * w).sum() / scl)
        cy = float((p[sel, 1] * w).sum() / scl)
        near = np.hypot(p[:, 0] - cx, p[:, 1] - cy) < 0.6
        return np.asarray(near)

    def _estimate(self, scan: LaserScan) -> None:
        p, w = self.particles, self.weights
        sel = self._cluster()
        ws = w[sel]
        sel_mass = ws.sum()  # the cluster's weight (summed once: the same sum each time)
        ws_sum = sel_mass
        if ws_sum <= 0:
            ws = np.ones(int(sel.sum()))
            ws_sum = ws.sum()
        ws = ws / ws_sum
        mx = float(ws @ p[sel, 0])
        my = float(ws @ p[sel, 1])
        myaw = math.atan2(float(ws @ np.sin(p[sel, 2])), float(ws @ np.cos(p[sel, 2])))
        mean = Pose2D(mx, my, myaw)
        pts = scan.points(self.laser_pose, max_beams=self.cfg.scan_match_beams,
                          range_max_m=scan.range_max_m - 0.05)
        self.unimodal = float(sel_mass) >= 0.8 * float(w.sum())
        # The prior whenever the filter tracks (a match was accepted, or the odometry carried
        # the estimate, since the last search), even when the particles do not agree on one
        # place: a scan that sees one or two distant shapes pins the pose down along some
        # directions only; the cloud smears along the others until its heaviest 0.5 m bin no
        # longer holds most of the weight, and the odometry's prediction is a better guess
        # there than whichever part of the smear is heaviest. While hypotheses compete after a
        # global search there is no track: the particle filter decides between them.
        guess, prior_cov = self._tracking_prior(mean, pts)
        if self.cfg.scan_match and len(pts) >= (3 if prior_cov is not None else 10):
            m = scan_match(self.field, pts, guess,
                           max_residual_m=self.cfg.scan_match_max_residual_m,
                           inlier_m=self.cfg.inlier_distance_m, prior_cov=prior_cov)
            self.inlier_fraction = self._fit(pts, m.pose)
            self.track_cov = None
            jump = m.pose.distance_to(guess)  # how far the match moved from where it began
            if self.inlier_fraction >= self.cfg.lost_inlier_fraction and jump < 0.3:
                # Floor: 1 cm, 0.3° (map resolution, unmodelled errors), never overconfident.
                self.track_cov = m.covariance + _COV_FLOOR
                self._shift(sel, mean, m.pose)
                mean = m.pose
        else:
            self.inlier_fraction = self._fit(pts, mean)
            self.track_cov = None
            if self.cfg.scan_match and prior_cov is not None:
                # Too few beams hit anything to match: trust the odometry (dead reckoning).
                self.track_cov = prior_cov
                self._shift(sel, mean, guess)
                mean = guess
        q = p[sel]
        dx = q[:, 0] - mean.x
        dy = q[:, 1] - mean.y
        dt = wrap_angles(q[:, 2] - mean.yaw)
        dev = np.stack([dx, dy, dt], axis=1)
        cov = (dev * ws[:, None]).T @ dev
        self.covariance = cov + _COV_FLOOR
        self.pose = mean
        self._update_state()

    def _shift(self, sel: npt.NDArray[np.bool_], mean: Pose2D, target: Pose2D) -> None:
        """Move the particles ``sel`` rigidly so that their mean ``mean`` lands on ``target``."""
        p = self.particles
        corr = target @ mean.inverse()
        c, s = math.cos(corr.yaw), math.sin(corr.yaw)
        q = p[sel]
        nx = corr.x + c * q[:, 0] - s * q[:, 1]
        ny = corr.y + s * q[:, 0] + c * q[:, 1]
        q[:, 0], q[:, 1] = nx, ny
        q[:, 2] = wrap_angles(q[:, 2] + corr.yaw)
        p[sel] = q

    def _predict_track(self) -> tuple[Pose2D, F64] | None:
        """The last estimate moved by the odometry increment and its grown covariance."""
        cov0 = self.track_cov
        if cov0 is None or self.search is not None or self.state == "lost":
            return None
        d = self._delta
        pred = self.pose @ d
        trans = math.hypot(d.x, d.y)
        rot = abs(d.yaw)
        a1, a2, a3, a4 = (self.cfg.odom_alpha1, self.cfg.odom_alpha2, self.cfg.odom_alpha3,
                          self.cfg.odom_alpha4)
        var_t = a3 * trans**2 + a4 * rot**2 + 1e-6
        var_r = a1 * rot**2 + a2 * trans**2 + 1e-6
        c, s = math.cos(self.pose.yaw), math.sin(self.pose.yaw)
        jac = np.array([[1.0, 0.0, -s * d.x - c * d.y],
                        [0.0, 1.0, c * d.x - s * d.y],
                        [0.0, 0.0, 1.0]])
        noise = np.array([[var_t, 0.0, 0.0], [0.0, var_t, 0.0], [0.0, 0.0, var_r]])
        cov = jac @ cov0 @ jac.T + noise
        return pred, np.asarray(cov, dtype=np.float64)

    def _beam_classes(self, pts: F64, pose: Pose2D) -> tuple[npt.NDArray[np.int8], F64]:
        """What each beam end of ``pts`` (``base_link``) says about ``pose`` — ``AGAINST``,
        ``ON_WALL`` or ``IN_FRONT`` of the map
        (:func:`~curio.estimation.localization_kernels.beam_evidence`) — and the distance
        field at each end (metres, what :meth:`DistanceField.lookup` reads there)."""
        f = self.field
        laser = pose @ self.laser_pose
        if f._rotated:
            wx, wy = self._world(pts, pose)
            ex, ey = f.to_local(wx, wy)
            llx, lly = f.to_local(np.array([laser.x]), np.array([laser.y]))
            lx, ly = float(llx[0]), float(lly[0])
            ex = np.ascontiguousarray(ex, dtype=np.float64)
            ey = np.ascontiguousarray(ey, dtype=np.float64)
        else:  # the arithmetic of ``_world`` and ``to_local``, compiled
            ex, ey = np.empty(len(pts)), np.empty(len(pts))
            ends_local(pose.x, pose.y, math.cos(pose.yaw), math.sin(pose.yaw),
                       np.ascontiguousarray(pts, dtype=np.float64), f.origin.x, f.origin.y,
                       ex, ey)
            lx, ly = laser.x - f.origin.x, laser.y - f.origin.y
        out = np.empty(len(pts), dtype=np.int8)
        end_dist: F64 = np.empty(len(pts))
        beam_evidence(f.dist_m, self._free_cells, self.grid.resolution_m, f.max_dist_m, lx, ly,
                      ex, ey, self.cfg.inlier_distance_m, out, end_dist)
        if np.count_nonzero(out == IN_FRONT) > 1:
            self._wide_in_front_against(pts, out)
        return out, end_dist

    def _wide_in_front_against(self, pts: F64, cls: npt.NDArray[np.int8]) -> None:
        """Mark ``AGAINST`` the ends in front of the map (``pts`` in ``base_link``, in scan
        order) that lie on a straight surface wider than ``MAX_UNMAPPED_WIDTH_M``.

        A person, a bag or a bin is narrow, and a group of people is a row of curved
        surfaces; a wall seen from a wrong pose (the rover carried into the next room, where
        half the beams end in the free space of the old one) is a long straight run of ends
        in front of the map. Neighbouring ends are on one surface when they are within
        ``JOIN_GAP_M``, or four beam spacings at their range (at most ``MAX_JOIN_GAP_M``: in
        an open field the valid returns can be far apart); a surface is cut where it bends by
        more than ``STRAIGHT_TOLERANCE_M`` from the line between its ends (corners, and the
        people of a group), and the straight pieces of ``MIN_WALL_BEAMS`` ends or more that
        are wider than the limit are walls."""
        front = cls == IN_FRONT
        if not np.any(front[:-1] & front[1:]):
            return  # no two neighbours in front of the map: every piece is one end, 0 m wide
        rel = pts - np.array([self.laser_pose.x, self.laser_pose.y])
        rng = np.hypot(rel[:, 0], rel[:, 1])
        step = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
        spacing = np.abs(wrap_angles(np.diff(np.arctan2(rel[:, 1], rel[:, 0]))))
        reach = np.clip(4.0 * np.minimum(rng[:-1], rng[1:]) * spacing, JOIN_GAP_M,
                        MAX_JOIN_GAP_M)
        joined = (step <= reach) & front[:-1] & front[1:]
        starts = np.flatnonzero(front & ~np.concatenate(([False], joined)))
        ends = np.flatnonzero(front & ~np.concatenate((joined, [False])))
        width = np.hypot(pts[ends, 0] - pts[starts, 0], pts[ends, 1] - pts[starts, 1])
        pieces = [(int(i), int(j)) for i, j, w in zip(starts, ends, width, strict=True)
                  if w > MAX_UNMAPPED_WIDTH_M]
        while pieces:
            i, j = pieces.pop()
            ax, ay = pts[i]
            dx, dy = pts[j, 0] - ax, pts[j, 1] - ay
            length = math.hypot(dx, dy)
            if length <= MAX_UNMAPPED_WIDTH_M or j - i + 1 < MIN_WALL_BEAMS:
                continue
            off = np.abs((pts[i:j + 1, 0] - ax) * dy - (pts[i:j + 1, 1] - ay) * dx) / length
            k = int(np.argmax(off))
            if off[k] > STRAIGHT_TOLERANCE_M and 0 < k < j - i:
                pieces += [(i, i + k), (i + k, j)]
            else:
                cls[i:j + 1] = AGAINST

    def _fit(self, pts: F64, pose: Pose2D) -> float:
        """How well the scan's ends ``pts`` (``base_link``) fit the map at ``pose``, 0–1: the
        share of the beams that end within the inlier distance of a wall face, a beam that
        stops in front of the map counting ``IN_FRONT_WEIGHT`` of one.

        A beam that stops in known-free space without passing a wall (``IN_FRONT``: a
        visitor's legs, a bag the map lacks) is explained, less well than one on a wall (the
        short readings of a beam model): at the right pose among a crowd two thirds of the
        beams can end on people, and a share counted without them read "lost" where the rest
        fit the walls exactly (the crowd benchmark's 20-visitor starts, which the search then
        moved 14 m away). Counted in full, a wrong pose in an open place, where most ends
        fall in free space, would fit as well as the right one; and ends in front of the map
        that lie on one wide surface (a wall seen from a wrong pose, not a person) count
        against it (:meth:`_wide_in_front_against`), as does a beam through a wall or into
        unknown space. The fit is never below the share of the ends on a wall.
        """
        if len(pts) == 0:
            return 0.0
        return self._fit_of(self._beam_classes(pts, pose)[0])

    @staticmethod
    def _fit_of(cls: npt.NDArray[np.int8]) -> float:
        """:meth:`_fit` of beams already classified (``cls`` not empty)."""
        on_wall = int(np.count_nonzero(cls == ON_WALL))
        in_front = int(np.count_nonzero(cls == IN_FRONT))
        return (on_wall + IN_FRONT_WEIGHT * in_front) / len(cls)

    def _without_unmapped(self, pts: F64, pose: Pose2D) -> F64:
        """``pts`` (``base_link``) without the beams that end deep in front of the map at the
        predicted ``pose``, for weighing the particles (a distance filter: Fox, Burgard and
        Thrun, "Markov localization for mobile robots in dynamic environments", 1999).

        Such an end (``IN_FRONT`` and at least ``UNMAPPED_MARGIN_M``, or twice the position
        spread, from any wall) is a person or a thing the map lacks: near the prediction it
        fits no particle, and far from it, where it may fall on a wall by chance, it pulls the
        particles to a wrong place (a crowd around a rover whose pose was just set). Every beam
        is kept when the scan fits the prediction poorly (:meth:`_fit` below
        ``lost_inlier_fraction``: a rover carried away must be judged on all it sees), or when
        too few beams would remain (``MIN_EVIDENCE_SHARE``, ``MIN_EVIDENCE_BEAMS``)."""
        n = len(pts)
        cls, end_dist = self._beam_classes(pts, pose)
        if self._fit_of(cls) < self.cfg.lost_inlier_fraction:
            return pts  # the prediction itself fits poorly (carried away?): judge on every beam
        d = end_dist - 0.5 * self.grid.resolution_m
        keep = ~((cls == IN_FRONT) & (d >= max(UNMAPPED_MARGIN_M, 2.0 * self.std_xy_m)))
        kept = int(np.count_nonzero(keep))
        if kept == n or kept < max(MIN_EVIDENCE_BEAMS, MIN_EVIDENCE_SHARE * n):
            return pts
        out: F64 = pts[keep]
        return out

    def _tracking_prior(self, mean: Pose2D, pts: F64) -> tuple[Pose2D, F64 | None]:
        """Where to start the scan match, and the prior covariance (None: no prior).

        While tracking, the prior is the last estimate moved by the odometry increment, its
        covariance grown by the odometry noise model (``odom_alpha1..4``). In a sparse world a
        scan that hits one distant shape leaves some directions unconstrained; there the
        particle cluster's mean random-walks with the resampling noise, while the odometry
        (fused wheels + gyro) is good to a few mm per metre. If the particle cluster disagrees
        with the prediction beyond 4 σ, the particles win and the prior is dropped for this scan
        only if the scan clearly fits better there (at least 20 beams, 0.2 more of them on a
        wall face): with a handful of beams a few random particles fit as well by chance
        somewhere else. A kidnapping still shows as a poor fit, hence ``lost`` and a search.
        """
        track = self._predict_track()
        if track is None:
            return mean, None
        pred, cov = track
        dev = np.array([mean.x - pred.x, mean.y - pred.y, wrap_angle(mean.yaw - pred.yaw)])
        gate = cov + self.covariance
        try:
            m2 = float(dev @ np.linalg.solve(gate, dev))
        except np.linalg.LinAlgError:
            return mean, None
        if m2 > 16.0 and len(pts) >= 20 and self._fit(pts, mean) >= self._fit(pts, pred) + 0.2:
            return mean, None
        return pred, np.asarray(cov, dtype=np.float64)

    @staticmethod
    def _world(pts: F64, pose: Pose2D) -> tuple[F64, F64]:
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        return (pose.x + c * pts[:, 0] - s * pts[:, 1], pose.y + s * pts[:, 0] + c * pts[:, 1])

    def _update_state(self) -> None:
        std_xy = math.sqrt(max(self.covariance[0, 0], self.covariance[1, 1]))
        std_yaw = math.sqrt(self.covariance[2, 2])
        poor = self.inlier_fraction < self.cfg.lost_inlier_fraction
        mediocre = self.inlier_fraction < self.cfg.ok_inlier_fraction
        self.poor_scans = self.poor_scans + 1 if poor else 0
        self.mediocre_scans = self.mediocre_scans + 1 if mediocre else 0
        if self.poor_scans >= self.cfg.lost_after_scans or std_xy > self.cfg.lost_std_xy_m:
            self.state = "lost"
            if self.cfg.auto_relocalize and self.search is None:
                self._start_search()
        elif mediocre or std_xy > 0.2 or std_yaw > 0.2 or self.search is not None:
            self.state = "uncertain"
            # A middling fit for a long time: maybe a look-alike place. Check the whole map;
            # the current pose stays a candidate, so a right pose amid clutter is kept.
            if self._recheck_due(parked=False):
                self._start_search(recheck=True)
        else:
            self.state = "ok"
            self.ok_since_set = True

    def _recheck_due(self, parked: bool) -> bool:
        """Whether a middling fit has lasted ``recheck_after_scans`` updates (or, ``parked``,
        stationary checks) and the whole-map re-check may run: not within
        ``recheck_after_set_m`` of driving after a pose was set, unless the rover is parked and
        was ``ok`` since (then the map fitted where the pose was set)."""
        cfg = self.cfg
        return (cfg.auto_relocalize and self.search is None
                and self.mediocre_scans >= cfg.recheck_after_scans
                and (self.since_set_m >= cfg.recheck_after_set_m
                     or (parked and self.ok_since_set)))

    def _resample(self) -> None:
        w = self.weights
        n_eff = 1.0 / float(np.sum(w**2))
        n = len(w)
        if n_eff > 0.5 * n and n >= self.cfg.min_particles:
            return
        n_max = self.cfg.max_particles
        # Systematic resampling to n_max, then KLD: keep the shortest random prefix that is
        # large enough for the number of histogram bins it occupies.
        positions = (self.rng.random() + np.arange(n_max)) / n_max
        cum = np.cumsum(w)
        cum[-1] = 1.0
        idx = np.searchsorted(cum, positions)
        idx = idx[self.rng.permutation(n_max)]
        cand = self.particles[idx]
        bins = self._bins(cand)
        _, first = np.unique(bins, return_index=True)
        is_new = np.zeros(n_max, dtype=np.float64)
        is_new[first] = 1.0
        k = np.cumsum(is_new)
        need = _kld_bound(k, self.cfg.kld_err, self.cfg.kld_z)
        count = np.arange(1, n_max + 1)
        ok = np.flatnonzero(count >= need)
        n_new = int(count[ok[0]]) if len(ok) else n_max
        n_new = max(self.cfg.min_particles, min(n_max, n_new))
        new = cand[:n_new].copy()
        # Random-particle injection (augmented MCL).
        if self.w_slow > 0.0:
            p_rand = max(0.0, 1.0 - self.w_fast / self.w_slow)
            n_rand = int(self.rng.binomial(n_new, min(p_rand, 0.5)))
            if n_rand:
                new[:n_rand] = self._random_poses(n_rand)
        self.particles = new
        self.weights = np.full(n_new, 1.0 / n_new)

    # --- global search -----------------------------------------------------------------------
    def _start_search(self, recheck: bool = False) -> None:
        step = max(1, round(self.cfg.global_step_m / self.grid.resolution_m))
        free = self.grid.free_mask() & (self.field.dist_m >= 0.2)
        sub = np.zeros_like(free)
        sub[step // 2::step, step // 2::step] = True
        rows, cols = np.nonzero(free & sub)
        if len(rows) == 0:
            rows, cols = np.nonzero(self.grid.free_mask())
        local = (np.stack([cols, rows], axis=1).astype(np.float64) + 0.5) * self.grid.resolution_m
        xy = self.grid.origin.transform_points(local)
        n_yaw = max(4, round(2 * math.pi / self.cfg.global_yaw_step_rad))
        yaws = np.asarray(-math.pi + (np.arange(n_yaw) + 0.5) * (2 * math.pi / n_yaw),
                          dtype=np.float64)
        # Shuffling the indices draws what shuffling the (M, 3) list did: the same order.
        order = self.rng.permutation(np.arange(len(xy) * n_yaw, dtype=np.int32))
        self.search = _GlobalSearch(xy, yaws, order, recheck=recheck)
        self.searches += 1
        log.info("global localisation: searching %d poses", len(order))

    def _propagate_top(self, delta: Pose2D) -> None:
        s = self.search
        if s is None or s.top is None:
            return
        t = s.top
        c, sn = np.cos(t[:, 2]), np.sin(t[:, 2])
        t[:, 0] += c * delta.x - sn * delta.y
        t[:, 1] += sn * delta.x + c * delta.y
        t[:, 2] = wrap_angles(t[:, 2] + delta.yaw)

    def _search_step(self, scan: LaserScan, pts_pf: F64) -> None:
        s = self.search
        assert s is not None
        pts = pts_pf[np.linspace(0, len(pts_pf) - 1, min(len(pts_pf), 36)).astype(int)]
        end = min(len(s), s.next_index + self.cfg.global_poses_per_scan)
        chunk = s.chunk(s.next_index, end)
        s.next_index = end
        score = self._loglik(chunk, pts, 0.2)
        k = min(60, len(chunk))
        top = np.argpartition(-score, k - 1)[:k]
        new = np.column_stack([chunk[top], score[top]])
        s.top = new if s.top is None else np.vstack([s.top, new])
        # Scores from different scans are not comparable (a scan seeing a long corridor scores
        # everything higher): keep a generous list, re-scored against one scan at the end.
        order = np.argsort(-s.top[:, 3])[:240]
        s.top = s.top[order]
        if s.next_index < len(s):
            return
        self._finish_search(scan)

    def _finish_search(self, scan: LaserScan) -> None:
        s = self.search
        assert s is not None and s.top is not None
        self.search = None
        pts = scan.points(self.laser_pose, max_beams=90, range_max_m=scan.range_max_m - 0.05)
        if len(pts):
            # Re-score against this scan, each candidate at its best of five headings across
            # its lattice cell (at 5 m a heading off by half a step misses a wall by 0.4 m).
            n_yaw = max(4, round(2 * math.pi / self.cfg.global_yaw_step_rad))
            offsets = np.linspace(-0.5, 0.5, 5) * (2 * math.pi / n_yaw)
            cand = np.repeat(s.top[:, :3], len(offsets), axis=0)
            cand[:, 2] = wrap_angles(cand[:, 2] + np.tile(offsets, len(s.top)))
            score = self._loglik(cand, pts, 0.2).reshape(len(s.top), len(offsets))
            best = np.argmax(score, axis=1)
            s.top[:, 2] = cand.reshape(len(s.top), len(offsets), 3)[np.arange(len(s.top)), best, 2]
            s.top = s.top[np.argsort(-score.max(axis=1))]
        results: list[tuple[float, Pose2D]] = []
        for row in s.top[:40]:
            guess = Pose2D(float(row[0]), float(row[1]), float(row[2]))
            m = scan_match(self.field, pts, guess, iterations=12, max_residual_m=0.4,
                           inlier_m=self.cfg.inlier_distance_m)
            m = scan_match(self.field, pts, m.pose, iterations=6,
                           max_residual_m=self.cfg.scan_match_max_residual_m,
                           inlier_m=self.cfg.inlier_distance_m)
            results.append((m.inlier_fraction, m.pose))
        current = scan_match(self.field, pts, self.pose, iterations=6,
                             max_residual_m=self.cfg.scan_match_max_residual_m,
                             inlier_m=self.cfg.inlier_distance_m)
        results.sort(key=lambda item: -item[0])
        elsewhere = [r for r in results if r[1].distance_to(current.pose) > 0.3
                     or abs(wrap_angle(r[1].yaw - current.pose.yaw)) > 0.3]
        if s.recheck and (not elsewhere
                          or elsewhere[0][0] < current.inlier_fraction + 0.15):
            # Nothing fits clearly better than where we are: keep the particle set.
            self.mediocre_scans = 0
            log.info("re-check: no place fits better than the current pose (%.2f)",
                     current.inlier_fraction)
            return
        results.append((current.inlier_fraction, current.pose))
        # Rank by a fine fit on every beam (within 5 cm of a wall face): the right place fits
        # to the sensor noise, a look-alike (repeated benches, symmetric rooms) only roughly.
        all_pts = scan.points(self.laser_pose, range_max_m=scan.range_max_m - 0.05)
        half = 0.5 * self.grid.resolution_m
        ranked: list[tuple[float, Pose2D]] = []
        free = self.grid.free_mask()
        for coarse, pose in results:
            row, col = self.grid.world_to_cell(pose.x, pose.y)
            if coarse < self.cfg.lost_inlier_fraction or not (
                    self.grid.in_bounds(row, col) and free[row, col]):
                continue  # a poor fit, or a match that slid off the map or into a wall
            d = self.field.lookup(*self._world(all_pts, pose)) - half
            ranked.append((float(np.mean(np.abs(d) <= 0.05)), pose))
        ranked.sort(key=lambda item: -item[0])
        hyps = _distinct_hypotheses(ranked)
        if not hyps:
            log.info("global localisation: no candidate fits; searching again")
            self._start_search()
            return
        self._seed_hypotheses(hyps)

    def _seed_hypotheses(self, hyps: list[tuple[float, Pose2D]]) -> None:
        """Restart the particle filter around the hypotheses ``(fit, pose in map)``, best
        first."""
        n_each = max(50, self.cfg.min_particles // len(hyps))
        parts = []
        for _, pose in hyps:
            q = np.empty((n_each, 3))
            q[:, 0] = pose.x + self.rng.normal(0, 0.05, n_each)
            q[:, 1] = pose.y + self.rng.normal(0, 0.05, n_each)
            q[:, 2] = wrap_angles(pose.yaw + self.rng.normal(0, 0.03, n_each))
            q[0] = pose.as_tuple()
            parts.append(q)
        self.particles = np.vstack(parts)
        self.weights = np.full(len(self.particles), 1.0 / len(self.particles))
        self.poor_scans = 0
        self.mediocre_scans = 0
        self.w_slow = self.w_fast = 0.0
        self.pose = hyps[0][1]
        self.track_cov = None
        self.unimodal = len(hyps) == 1
        self.state = "uncertain"
        self._force_update = True
        log.info("global localisation: %d hypotheses, best at %s (fit %.2f)", len(hyps),
                 hyps[0][1], hyps[0][0])

    @property
    def std_xy_m(self) -> float:
        """Standard deviation of the position estimate (larger axis), metres."""
        return math.sqrt(max(self.covariance[0, 0], self.covariance[1, 1]))

    @property
    def std_yaw_rad(self) -> float:
        """Standard deviation of the heading estimate, radians."""
        return math.sqrt(self.covariance[2, 2])


HEALTH_PERIOD_S = 1.0


def localization_health(stamp: float, state: str, std_xy_m: float) -> DriverHealth:
    """``/health`` name ``localization``: ``ok``; ``degraded`` while uncertain (searching);
    ``error`` when lost (the navigator holds the rover still) — with what to do."""
    if state == "lost":
        return DriverHealth(stamp, "localization", "error",
                            "lost: the rover does not know where it is and holds still while "
                            "it searches; if it does not find itself, set its position on the "
                            "map", {"std_xy_m": round(std_xy_m, 3)})
    if state == "uncertain":
        return DriverHealth(stamp, "localization", "degraded",
                            f"uncertain (spread {std_xy_m:.2f} m): the scans do not match the "
                            "map well; searching", {"std_xy_m": round(std_xy_m, 3)})
    return DriverHealth(stamp, "localization", "ok", "", {"std_xy_m": round(std_xy_m, 3)})


class BeamFilter(Protocol):
    """Names the returns that are not evidence about the pose: the people tracker
    (``curio/people/node.py``) knows which beams ended on a person."""

    def beams_to_ignore(self, scan: LaserScan,
                        laser_in_map: Pose2D) -> npt.NDArray[np.bool_] | None:
        """Beams of ``scan`` (its laser at ``laser_in_map``, the pose before this scan's
        update) the filter is not to use (None: use every return)."""


class LocalizerNode(MapOdomPublisher):
    """Bus adapter: ``SCAN`` + ``ODOM`` (+ ``INITIAL_POSE``) → ``POSE``, ``MAP_TO_ODOM``,
    ``LOCALIZATION``.

    ``POSE`` is published for every ``ODOM`` message as ``map→odom ∘ odom`` with the odometry
    stamp; the correction changes only after a filter update. With a ``beam_filter`` (the
    people tracker), returns on people are dropped from each scan before the update: a crowd
    hides the map, it does not contradict the pose (among visitors in an open hall most
    returns can be legs, and a fit counted over them reads as "lost" at the right pose).
    """

    def __init__(self, bus: Bus, clock: Clock, localizer: Localizer, start: Pose2D) -> None:
        """Filter updates run through ``clock.offload``: in a worker thread on the real clock,
        so a global-search step or a slow update never blocks the event loop; inline on a
        simulated clock, keeping runs deterministic."""
        super().__init__(bus)
        self.clock = clock
        self.localizer = localizer
        self.start = start
        self._working = False  # a worker thread owns the localiser
        self._pending: list[Callable[[], None]] = []  # requests made meanwhile, in order
        self._odom = PoseHistory(400, interpolation="se2")  # odometry poses in ``odom``
        self.update_times_s: list[float] = []
        self._health_state = ""
        self._health_due_s = -math.inf
        self._cov_array: F64 | None = None  # the covariance last converted, and its tuple
        self._cov_tuple: tuple[float, ...] = ()
        self.beam_filter: BeamFilter | None = None

    def _without_ignored(self, scan: LaserScan, odom_pose: Pose2D) -> LaserScan:
        """``scan`` with the beams the ``beam_filter`` names made invalid (``nan``)."""
        if self.beam_filter is None or self.map_to_odom is None:
            return scan
        laser_in_map = self.map_to_odom @ odom_pose @ self.localizer.laser_pose
        skip = self.beam_filter.beams_to_ignore(scan, laser_in_map)
        if skip is None or not skip.any():
            return scan
        ranges = scan.ranges_m.copy()
        ranges[skip] = np.nan
        return replace(scan, ranges_m=ranges)

    def global_localization(self) -> None:
        """Forget the pose and search the whole map (API for the dashboard and CLI)."""
        if self._working:
            self._pending.append(self.global_localization)
            return
        self.localizer.global_localization()
        self.publish_status(self.clock.now())

    def set_pose(self, pose: Pose2D, std_xy_m: float, std_yaw_rad: float) -> None:
        """Re-initialise around ``pose`` in ``map``."""
        if self._working:
            self._pending.append(lambda: self.set_pose(pose, std_xy_m, std_yaw_rad))
            return
        self.localizer.initialize(pose, std_xy_m, std_yaw_rad)
        latest = self._odom.latest()
        if latest is not None:
            self.set_correction(pose, latest[1], latest[0])

    def _odom_at(self, stamp: float) -> Pose2D | None:
        """Odometry pose at ``stamp``, interpolated along the motion between buffered ones."""
        return self._odom.at(stamp)

    def on_odom(self, odom: Odometry) -> None:
        """Buffer odometry and publish ``POSE`` = map→odom ∘ odom."""
        self._odom.add(odom.stamp, odom.pose)
        super().on_odom(odom)

    def initial_pose(self) -> Pose2D:
        """The start pose (the filter is initialised around it if it was not yet)."""
        if not self.localizer.initialized:
            self.localizer.initialize(self.start)
        return self.start

    def pose_covariance(self, odom: Odometry | None = None) -> tuple[float, ...]:
        """The filter's covariance (converted once per filter update: the localiser replaces
        the array, never writes into it, and ``POSE`` goes out with every odometry message)."""
        cov = self.localizer.covariance
        if cov is not self._cov_array:
            self._cov_array = cov
            self._cov_tuple = tuple(cov.ravel().tolist())
        return self._cov_tuple

    def on_scan(self, scan: LaserScan) -> None:
        """Run the filter on one scan and update the correction."""
        odom_pose = self._odom_at(scan.stamp)
        if odom_pose is None:
            return
        scan = self._without_ignored(scan, odom_pose)
        self._after_update(scan, odom_pose, self._timed_update(scan, odom_pose))

    def _timed_update(self, scan: LaserScan, odom_pose: Pose2D) -> float | None:
        """The filter update (thread-safe to run off the loop: touches the localiser only);
        its wall time in seconds, or None if the filter did not update."""
        from curio.core.clock import wall_perf_counter

        t0 = wall_perf_counter()
        if not self.localizer.update(scan, odom_pose):
            return None
        return wall_perf_counter() - t0

    def _after_update(self, scan: LaserScan, odom_pose: Pose2D, took_s: float | None) -> None:
        """Publish what an update changed (on the loop)."""
        if took_s is None:
            return
        self.update_times_s.append(took_s)
        if len(self.update_times_s) > 1000:
            del self.update_times_s[:500]
        if self.localizer.state != "lost" or self.localizer.search is None:
            self.set_correction(self.localizer.pose, odom_pose, scan.stamp)
            latest = self._odom.latest()
            assert latest is not None  # the update used an odometry pose
            # The correction at once, not with the next odometry.
            self.publish_pose(*latest, self.pose_covariance())
        self.publish_status(scan.stamp)

    def on_initial_pose(self, msg: PoseWithCovariance) -> None:
        """``INITIAL_POSE``: a huge covariance asks for global localisation."""
        cov = msg.covariance
        std_xy = math.sqrt(max(cov[0], cov[4], 0.0))
        std_yaw = math.sqrt(max(cov[8], 0.0))
        if std_xy > self.localizer.cfg.global_std_xy_m:
            self.global_localization()
        else:
            self.set_pose(msg.pose, max(std_xy, 0.01), max(std_yaw, 0.01))
            self.publish_status(self.clock.now())

    def publish_status(self, stamp: float) -> None:
        """``LOCALIZATION``: the filter's state and spread; ``/health`` (name
        ``localization``) when the state changes and every ``HEALTH_PERIOD_S``."""
        loc = self.localizer
        self.bus.publish(LOCALIZATION, LocalizationStatus(
            stamp, loc.state, len(loc.particles), loc.std_xy_m, loc.std_yaw_rad))
        if loc.state != self._health_state or stamp >= self._health_due_s:
            self._health_state = loc.state
            self._health_due_s = stamp + HEALTH_PERIOD_S
            self.bus.publish(HEALTH, localization_health(stamp, loc.state, loc.std_xy_m))

    async def run(self) -> None:
        """Consume odometry, scans and initial poses until cancelled."""
        import asyncio

        odom_sub = self.bus.subscribe(ODOM, maxsize=64)
        scan_sub = self.bus.subscribe(SCAN, maxsize=1)
        init_sub = self.bus.subscribe(INITIAL_POSE)

        async def odometry() -> None:
            async for o in odom_sub:
                self.on_odom(o)

        async def scans() -> None:
            async for s in scan_sub:
                for o in odom_sub.drain():  # the odometry up to the scan's time first
                    self.on_odom(o)
                odom_pose = self._odom_at(s.stamp)
                if odom_pose is None:
                    continue
                s = self._without_ignored(s, odom_pose)
                self._working = True
                try:
                    took = await self.clock.offload(self._timed_update, s, odom_pose)
                finally:
                    self._working = False
                self._after_update(s, odom_pose, took)
                while self._pending:  # requests that came in during the update
                    self._pending.pop(0)()

        async def initial_poses() -> None:
            async for m in init_sub:
                self.on_initial_pose(m)

        try:
            await asyncio.gather(odometry(), scans(), initial_poses())
        finally:
            odom_sub.close()
            scan_sub.close()
            init_sub.close()
