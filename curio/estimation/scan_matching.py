"""Scan matching for mapping: a correlative branch-and-bound search, then point-to-line refinement.

Two matchers work in tandem — the split between a robust *global* search and a precise *local*
refinement that Cartographer (real-time correlative scan matcher, then Ceres) and Karto (coarse,
then fine correlation) also make:

* :class:`LikelihoodGrid` + :meth:`LikelihoodGrid.search` — correlative scan matching (E. Olson,
  *Real-time correlative scan matching*, ICRA 2009): the reference points are drawn into a
  grid of ``exp(−d²/2σ²)`` and every pose in a window (translations on the grid's cells,
  rotations on a fan) is scored by the mean grid value under the scan's points. The search is
  the exact branch and bound of Hess et al. (*Real-time loop closure in 2D LIDAR SLAM*, ICRA
  2016): a pyramid of max-pooled grids bounds whole blocks of translations, so only promising
  blocks are refined. It finds the right basin even when the guess is off by many cells or
  degrees (odometry slip, a loop closure after a long drift), but only to a cell and a
  rotation step.
* :class:`PointMap` + :func:`refine` — point-to-line ICP (A. Censi, *An ICP variant using a
  point-to-line metric*, ICRA 2008) on the reference points with their surface normals,
  Gauss–Newton with a Cauchy-weighted residual, optionally a maximum a posteriori estimate with
  a Gaussian prior (the odometry). It gives millimetre-level poses *and* the information
  matrix ``JᵀWJ/σ²`` of the fit: along a featureless corridor every normal is perpendicular to
  the axis, the matrix has (almost) nothing along it, and the covariance says so — the pose
  graph then lets other constraints, or the odometry prior, decide that direction.

Frames: scan points are in the sensor's frame (``base_link``), reference points and poses in the
reference frame (``map``, or a submap's anchor frame). Metres and radians throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, wrap_angle
from curio.estimation.scan_matching_kernels import branch_and_bound, max_pyramid, splat_points

__all__ = [
    "LikelihoodGrid",
    "PointMap",
    "Refined",
    "refine",
    "scan_normals",
    "voxel_subsample",
]

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]


def scan_normals(points: F64, half_window: int = 2, gap_m: float = 0.12,
                 gap_per_m: float = 0.03, max_flatness: float = 0.15,
                 noise_m: float = 0.015) -> tuple[F64, B]:
    """Unit surface normals of scan points given in beam order, and which are trustworthy.

    Each point's normal is that of the line fitted (principal axes) to itself and its
    ``half_window`` neighbours on either side in beam order that lie within
    ``gap_m + gap_per_m · range`` of it; it is trusted when at least three points took part and
    the spread across the line (RMS) is at most ``noise_m`` or ``max_flatness`` of the spread
    along it.

    Args:
        points: ``(N, 2)`` end points in beam order, sensor frame, metres.

    Returns:
        ``(normals (N, 2), ok (N,))`` in the points' frame.
    """
    n = len(points)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    offs = np.arange(-half_window, half_window + 1)
    idx = np.arange(n)[:, None] + offs[None, :]
    valid = (idx >= 0) & (idx < n)
    nb = points[np.clip(idx, 0, n - 1)]
    dist = np.linalg.norm(nb - points[:, None, :], axis=2)
    rng = np.linalg.norm(points, axis=1)
    valid &= dist <= (gap_m + gap_per_m * rng)[:, None]
    cnt = valid.sum(axis=1)
    w = valid.astype(np.float64)
    mean = (nb * w[:, :, None]).sum(axis=1) / np.maximum(cnt, 1)[:, None]
    c = (nb - mean[:, None, :]) * w[:, :, None]
    sxx = (c[:, :, 0] ** 2).sum(axis=1)
    syy = (c[:, :, 1] ** 2).sum(axis=1)
    sxy = (c[:, :, 0] * c[:, :, 1]).sum(axis=1)
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # direction of the line
    normals = np.stack([-np.sin(phi), np.cos(phi)], axis=1)
    tr = sxx + syy
    det = sxx * syy - sxy**2
    disc = np.sqrt(np.maximum(0.25 * tr**2 - det, 0.0))
    lam_max = 0.5 * tr + disc
    lam_min = np.maximum(0.5 * tr - disc, 0.0)
    ok = (cnt >= 3) & (lam_min <= max_flatness**2 * lam_max + cnt * noise_m**2)
    return normals, ok


def voxel_subsample(points: F64, cell_m: float) -> npt.NDArray[np.int64]:
    """Indices keeping one point (the first) per ``cell_m`` square cell, in input order."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    keys = np.floor(points / cell_m).astype(np.int64)
    key = keys[:, 0] * 1_000_003 + keys[:, 1]
    _, first = np.unique(key, return_index=True)
    return np.sort(first).astype(np.int64)


class LikelihoodGrid:
    """Reference points drawn as a likelihood grid, with the max pyramid for branch and bound.

    Args:
        points: ``(M, 2)`` reference points, reference frame, metres.
        resolution_m: cell size.
        sigma_m: the spread of each point's Gaussian.
        depth: pyramid levels above the grid (blocks of up to ``2^depth`` cells).
        bounds: optional ``(xmin, ymin, xmax, ymax)`` to crop the grid to, metres.
    """

    def __init__(self, points: F64, resolution_m: float = 0.05, sigma_m: float = 0.05,
                 depth: int = 3, bounds: tuple[float, float, float, float] | None = None) -> None:
        self.resolution_m = resolution_m
        self.depth = depth
        pad = 3.0 * sigma_m + resolution_m
        if bounds is None:
            if len(points):
                bounds = (float(points[:, 0].min()), float(points[:, 1].min()),
                          float(points[:, 0].max()), float(points[:, 1].max()))
            else:
                bounds = (0.0, 0.0, 0.0, 0.0)
        if bounds is not None and len(points):  # no wider than the points need
            bounds = (max(bounds[0], float(points[:, 0].min())),
                      max(bounds[1], float(points[:, 1].min())),
                      min(bounds[2], float(points[:, 0].max())),
                      min(bounds[3], float(points[:, 1].max())))
        xmin, ymin, xmax, ymax = bounds
        self.ox = math.floor((xmin - pad) / resolution_m) * resolution_m
        self.oy = math.floor((ymin - pad) / resolution_m) * resolution_m
        w = max(1, math.ceil((xmax + pad - self.ox) / resolution_m))
        h = max(1, math.ceil((ymax + pad - self.oy) / resolution_m))
        grid = np.zeros((h, w), dtype=np.float32)
        if len(points):
            splat_points(np.ascontiguousarray(points, dtype=np.float64), self.ox, self.oy,
                         resolution_m, sigma_m, grid)
        self.grid = grid
        self.pyramid = max_pyramid(grid, depth)

    def score(self, points: F64, pose: Pose2D) -> float:
        """Mean grid value under ``points`` (sensor frame) placed at ``pose``."""
        if len(points) == 0:
            return 0.0
        w = pose.transform_points(points)
        c = np.floor((w[:, 0] - self.ox) / self.resolution_m).astype(np.int64)
        r = np.floor((w[:, 1] - self.oy) / self.resolution_m).astype(np.int64)
        h, wd = self.grid.shape
        ok = (r >= 0) & (r < h) & (c >= 0) & (c < wd)
        return float(self.grid[r[ok], c[ok]].sum()) / len(points)

    def search(self, points: F64, center: Pose2D, window_m: float, window_rad: float,
               step_rad: float, min_score: float = 0.0,
               exclude: tuple[Pose2D, float, float] | None = None) -> tuple[Pose2D, float] | None:
        """The best pose of ``points`` within ``±window_m`` and ``±window_rad`` of ``center``.

        Translations are searched on the grid's cells, rotations every ``step_rad``; the best
        mean grid value must reach ``min_score`` (0..1). ``exclude = (pose, radius_m,
        radius_rad)`` leaves out the solutions that close to ``pose`` (a previous result of the
        same search): the runner-up peak.

        Returns:
            ``(pose, score)`` or None when nothing reaches ``min_score``.
        """
        if len(points) == 0:
            return None
        cells = max(0, math.ceil(window_m / self.resolution_m))
        n_rot = max(0, math.ceil(window_rad / step_rad))
        ex_i = ex_j = ex_k = ex_rot = 0
        ex_cells = -1
        if exclude is not None:
            ex_pose, ex_m, ex_rad = exclude
            ex_j = round((ex_pose.x - center.x) / self.resolution_m)
            ex_i = round((ex_pose.y - center.y) / self.resolution_m)
            ex_k = round(wrap_angle(ex_pose.yaw - center.yaw) / step_rad)
            ex_cells = math.ceil(ex_m / self.resolution_m)
            ex_rot = math.ceil(ex_rad / step_rad)
        score, dx, dy, dth, _ = branch_and_bound(
            self.pyramid, self.ox, self.oy, self.resolution_m,
            np.ascontiguousarray(points, dtype=np.float64), center.x, center.y, center.yaw,
            cells, n_rot, step_rad, min_score, ex_i, ex_j, ex_k, ex_cells, ex_rot)
        if score < 0.0:
            return None
        return Pose2D(center.x + dx, center.y + dy, wrap_angle(center.yaw + dth)), float(score)


class PointMap:
    """Reference points with trusted normals, indexed by a k-d tree (for :func:`refine`).

    Args:
        points: ``(M, 2)`` reference points, reference frame, metres.
        normals: ``(M, 2)`` their unit normals in the same frame.
    """

    def __init__(self, points: F64, normals: F64) -> None:
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        from scipy.spatial import cKDTree  # here: scipy.spatial is ~12 MB, mapping only

        self.tree = cKDTree(self.points) if len(self.points) else None

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True, slots=True)
class Refined:
    """Outcome of :func:`refine`.

    Attributes:
        pose: the refined pose in the reference frame.
        info: 3×3 information of the scan fit alone (x m, y m, yaw rad in the reference frame;
            ``JᵀWJ / σ²``) — small along directions the scan leaves open.
        info_total: ``info`` plus the prior's information (the posterior), if there was one.
        inlier_fraction: share of the scan's points within ``inlier_m`` of a reference line.
        rms_m: RMS point-to-line residual of the inliers.
        inliers: number of inlier points.
    """

    pose: Pose2D
    info: F64
    info_total: F64
    inlier_fraction: float
    rms_m: float
    inliers: int


def _jacobian(points: F64, normals: F64, th: float) -> F64:
    c, s = math.cos(th), math.sin(th)
    # d(R p)/dθ = (−s px − c py, c px − s py)
    drx = -s * points[:, 0] - c * points[:, 1]
    dry = c * points[:, 0] - s * points[:, 1]
    return np.stack([normals[:, 0], normals[:, 1], normals[:, 0] * drx + normals[:, 1] * dry],
                    axis=1)


def refine(pmap: PointMap, points: F64, guess: Pose2D, *, sigma_m: float = 0.03,
           max_dist_m: tuple[float, ...] = (0.5, 0.3, 0.15, 0.1, 0.1, 0.1),
           inlier_m: float = 0.05, cauchy_m: float = 0.05,
           prior_mean: Pose2D | None = None, prior_info: F64 | None = None) -> Refined:
    """Point-to-line ICP of ``points`` (sensor frame) on ``pmap``, starting at ``guess``.

    One Gauss–Newton step per entry of ``max_dist_m`` (the largest distance of a point to its
    nearest reference point for the pair to count, shrinking as the pose converges); residuals
    are Cauchy-weighted with scale ``cauchy_m``. With ``prior_info`` (3×3, 1/m² and 1/rad², in
    the reference frame) the result is the maximum a posteriori pose given the prior centred on
    ``prior_mean`` (default ``guess``).
    """
    x, y, th = guess.x, guess.y, guess.yaw
    mu = guess if prior_mean is None else prior_mean
    info = np.zeros((3, 3))
    tree = pmap.tree
    if tree is None or len(points) < 3:
        return Refined(guess, info, info if prior_info is None else prior_info.copy(), 0.0,
                       float("inf"), 0)
    for dmax in max_dist_m:
        c, s = math.cos(th), math.sin(th)
        wx = x + c * points[:, 0] - s * points[:, 1]
        wy = y + s * points[:, 0] + c * points[:, 1]
        d, j = tree.query(np.stack([wx, wy], axis=1), distance_upper_bound=dmax)
        use = np.isfinite(d)
        if np.count_nonzero(use) < 6:
            break
        q = pmap.points[j[use]]
        nrm = pmap.normals[j[use]]
        r = nrm[:, 0] * (wx[use] - q[:, 0]) + nrm[:, 1] * (wy[use] - q[:, 1])
        jac = _jacobian(points[use], nrm, th)
        wgt = 1.0 / (1.0 + (r / cauchy_m) ** 2)
        jw = jac * (wgt / sigma_m**2)[:, None]
        info = jw.T @ jac
        g = jw.T @ r
        h = info + np.diag([1e-6, 1e-6, 1e-6])
        if prior_info is not None:
            dev = np.array([x - mu.x, y - mu.y, wrap_angle(th - mu.yaw)])
            h = h + prior_info
            g = g + prior_info @ dev
        step = -np.linalg.solve(h, g)
        x += float(step[0])
        y += float(step[1])
        th = wrap_angle(th + float(step[2]))
        if (dmax <= max_dist_m[-1] and abs(step[0]) < 1e-4 and abs(step[1]) < 1e-4
                and abs(step[2]) < 1e-4):
            break
    # Final residuals at the converged pose.
    pose = Pose2D(x, y, th)
    c, s = math.cos(th), math.sin(th)
    wx = x + c * points[:, 0] - s * points[:, 1]
    wy = y + s * points[:, 0] + c * points[:, 1]
    d, j = tree.query(np.stack([wx, wy], axis=1), distance_upper_bound=max_dist_m[-1])
    use = np.isfinite(d)
    q = pmap.points[j[use]]
    nrm = pmap.normals[j[use]]
    r = nrm[:, 0] * (wx[use] - q[:, 0]) + nrm[:, 1] * (wy[use] - q[:, 1])
    inl = np.abs(r) <= inlier_m
    n_inl = int(np.count_nonzero(inl))
    rms = float(np.sqrt(np.mean(r[inl] ** 2))) if n_inl else float("inf")
    total = info if prior_info is None else info + prior_info
    return Refined(pose, info, total, n_inl / len(points), rms, n_inl)
