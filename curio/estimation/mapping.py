"""Mapping a new building: scan matching, keyframes, loop closure on a pose graph.

:class:`ScanMapper` is the engine (no bus, no clock), fed with scans and the odometry at each
scan — online by :class:`MappingNode` (``SCAN`` + ``ODOM`` while the rover is driven) and offline
by :func:`build_map_from_log` (``curio map build``).

Per scan:

1. **Prediction** from odometry: the last corrected pose composed with the odometry increment.
2. **Scan matching** (Gauss–Newton on the bilinear distance field of a window of the map around
   the rover, first with a wide then with a tight outlier cut); the match is kept when enough
   beams fit, else the odometry guess is used. With ``odom_prior_fraction`` > 0 the match is a
   maximum a posteriori estimate with the prediction as a Gaussian prior (σ = 1 cm +
   fraction × travel, 0.3° + fraction × (turn + travel / 2)), so directions a scan leaves
   open (a corridor, the rotation while turning on the spot in front of one wall) follow the
   odometry instead of drifting. On the mapping benchmark, seeds 1–5, 0.2 against 0 (off):
   occupied agreement after alignment mean 98.3 % / min 96.7 % against 98.2 % / 95.7 %,
   unaligned mean 95.9 % against 93.2 % — a modest gain; single seeds still vary by ±2 %
   with small changes of the input.
3. **Keyframes** every ``keyframe_d_m`` / ``keyframe_a_rad`` of motion: the scan is added to the
   log-odds occupancy grid (free cells along each beam, an occupied cell at its end) and the
   distance-field window is rebuilt.
4. **Loop closure**: at a keyframe near (``loop_radius_m``) an old one that is far back along the
   trajectory (``loop_min_travel_m``), the scan is matched against a submap built from the old
   keyframe's neighbours — a brute-force correlative search (±``loop_search_m``,
   ±``loop_search_rad``) followed by Gauss–Newton — and an accepted match adds a constraint to
   the pose graph. The graph (keyframe poses; odometry/scan-match edges between consecutive
   keyframes and the loop edges) is solved by sparse Gauss–Newton (``scipy.sparse``), and the
   grid is rebuilt from the corrected keyframes.

Frames: the map is built in the frame of the first pose (``initial`` pose, default the origin);
odometry is ``base_link`` in ``odom``; scan points are in ``base_link``. Metres and radians.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from curio.core.geometry import Pose2D, wrap_angle, wrap_angles
from curio.estimation.carmen import LogScan
from curio.estimation.correction import MapOdomPublisher
from curio.estimation.localization import DistanceField, scan_match
from curio.estimation.maps import OccupancyGrid

if TYPE_CHECKING:
    from curio.core.bus import Bus
    from curio.core.clock import Clock
    from curio.core.messages import LaserScan, Odometry

__all__ = ["MapperParams", "MappingNode", "ScanMapper", "build_map_from_log", "optimize_pose_graph"]

log = logging.getLogger("curio.estimation.mapping")

F64 = npt.NDArray[np.float64]


@dataclass
class MapperParams:
    """Tuning of :class:`ScanMapper` (defaults suit a 360° 12 m lidar or a 180° SICK)."""

    resolution_m: float = 0.05
    max_range_m: float = 12.0
    no_return_clear_m: float = 3.0
    keyframe_d_m: float = 0.25
    keyframe_a_rad: float = 0.2
    match_beams: int = 200
    window_m: float = 14.0
    min_inlier_fraction: float = 0.35
    l_occ: float = 0.9
    l_free: float = -0.4
    l_max: float = 6.0
    loop_radius_m: float = 4.0
    loop_min_travel_m: float = 10.0
    loop_search_m: float = 1.2
    loop_search_rad: float = 0.35
    loop_min_inliers: float = 0.8
    loop_drift_fraction: float = 0.03
    loop_drift_rad_per_m: float = 0.003
    loop_neighbours: int = 12
    loop_cooldown: int = 15
    loop_try_every: int = 3
    odom_sigma_xy_m: float = 0.05
    odom_sigma_yaw_rad: float = 0.02
    loop_sigma_xy_m: float = 0.05
    loop_sigma_yaw_rad: float = 0.02
    odom_prior_fraction: float = 0.2  # > 0: scan matches are MAP around the odometry guess


@dataclass
class Keyframe:
    """A scan kept for the map: its pose in the map frame, points (base_link), laser origin."""

    pose: Pose2D
    points: F64
    no_return: F64  # (M, 2) unit-range directions in base_link of beams without a return
    laser: Pose2D
    travel_m: float


class LogOdds:
    """A growing log-odds grid; cell (0, 0)'s corner at ``origin`` (no rotation)."""

    def __init__(self, resolution_m: float, params: MapperParams) -> None:
        self.res = resolution_m
        self.p = params
        self.l: npt.NDArray[np.float32] = np.zeros((0, 0), dtype=np.float32)
        self.seen: npt.NDArray[np.bool_] = np.zeros((0, 0), dtype=bool)
        self.ox = 0.0
        self.oy = 0.0

    def _ensure(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        res = self.res
        if self.l.size == 0:
            pad = 10.0
            self.ox = math.floor((xmin - pad) / res) * res
            self.oy = math.floor((ymin - pad) / res) * res
            w = math.ceil((xmax - self.ox + pad) / res)
            h = math.ceil((ymax - self.oy + pad) / res)
            self.l = np.zeros((h, w), dtype=np.float32)
            self.seen = np.zeros((h, w), dtype=bool)
            return
        h, w = self.l.shape
        grow_l = max(0, math.ceil((self.ox - xmin) / res))
        grow_b = max(0, math.ceil((self.oy - ymin) / res))
        grow_r = max(0, math.ceil((xmax - (self.ox + w * res)) / res))
        grow_t = max(0, math.ceil((ymax - (self.oy + h * res)) / res))
        if grow_l or grow_b or grow_r or grow_t:
            step = round(8.0 / res)
            gl, gb, gr, gt = (g + step if g else 0 for g in (grow_l, grow_b, grow_r, grow_t))
            self.l = np.pad(self.l, ((gb, gt), (gl, gr)))
            self.seen = np.pad(self.seen, ((gb, gt), (gl, gr)))
            self.ox -= gl * res
            self.oy -= gb * res

    def integrate(self, origin_xy: tuple[float, float], ends: F64, clear_ends: F64) -> None:
        """One scan: rays from ``origin_xy`` to ``ends`` (hit) and to ``clear_ends`` (no hit)."""
        allp = np.vstack([ends, clear_ends, np.array([origin_xy])])
        self._ensure(float(allp[:, 0].min()), float(allp[:, 1].min()),
                     float(allp[:, 0].max()), float(allp[:, 1].max()))
        res = self.res
        w = self.l.shape[1]
        targets = np.vstack([ends, clear_ends])
        if len(targets) == 0:
            return
        dx = targets[:, 0] - origin_xy[0]
        dy = targets[:, 1] - origin_xy[1]
        length = np.hypot(dx, dy)
        n_hit = len(ends)
        occ = np.zeros(0, dtype=np.int64)
        if n_hit:
            cols = ((ends[:, 0] - self.ox) / res).astype(np.int64)
            rows = ((ends[:, 1] - self.oy) / res).astype(np.int64)
            occ = np.unique(rows * w + cols)
        # Free cells: samples every 0.8 cell up to one cell short of a hit (to the end if none);
        # a cell that is some beam's end point in this scan is not also marked free.
        stop = length.copy()
        stop[:n_hit] -= res
        steps = np.arange(0.0, float(stop.max(initial=0.0)), 0.8 * res)
        flat_l = self.l.reshape(-1)
        flat_seen = self.seen.reshape(-1)
        if len(steps):
            frac = steps[None, :] / np.maximum(length[:, None], 1e-9)
            mask = steps[None, :] < stop[:, None]
            fx = origin_xy[0] + dx[:, None] * frac
            fy = origin_xy[1] + dy[:, None] * frac
            cols = ((fx[mask] - self.ox) / res).astype(np.int64)
            rows = ((fy[mask] - self.oy) / res).astype(np.int64)
            free = np.setdiff1d(np.unique(rows * w + cols), occ, assume_unique=True)
            flat_l[free] += self.p.l_free
            flat_seen[free] = True
        if len(occ):
            flat_l[occ] += self.p.l_occ
            flat_seen[occ] = True
        np.clip(self.l, -self.p.l_max, self.p.l_max, out=self.l)

    def occupancy(self, crop: bool = True, margin_m: float = 1.0) -> OccupancyGrid:
        """The grid as map_server occupancy (−1 unknown, 0..100), cropped to the seen area."""
        prob = 1.0 / (1.0 + np.exp(-self.l.astype(np.float64)))
        data = np.rint(prob * 100.0).astype(np.int8)
        data[~self.seen] = -1
        ox, oy = self.ox, self.oy
        if crop and self.seen.any():
            rows, cols = np.nonzero(self.seen)
            m = round(margin_m / self.res)
            r0, r1 = max(0, rows.min() - m), min(self.seen.shape[0], rows.max() + m + 1)
            c0, c1 = max(0, cols.min() - m), min(self.seen.shape[1], cols.max() + m + 1)
            data = data[r0:r1, c0:c1]
            ox += c0 * self.res
            oy += r0 * self.res
        return OccupancyGrid(np.ascontiguousarray(data), self.res, Pose2D(ox, oy, 0.0))

    def window(self, cx: float, cy: float, half_m: float) -> OccupancyGrid:
        """The occupancy of a square window around (cx, cy) (for the distance field)."""
        res = self.res
        h, w = self.l.shape
        c0 = max(0, int((cx - half_m - self.ox) / res))
        c1 = min(w, int((cx + half_m - self.ox) / res) + 1)
        r0 = max(0, int((cy - half_m - self.oy) / res))
        r1 = min(h, int((cy + half_m - self.oy) / res) + 1)
        sub = self.l[r0:r1, c0:c1]
        data = np.where(sub > 0.5, 100, 0).astype(np.int8)
        return OccupancyGrid(data, res, Pose2D(self.ox + c0 * res, self.oy + r0 * res, 0.0))


def _v(p: Pose2D) -> tuple[float, float, float]:
    return (p.x, p.y, p.yaw)


def optimize_pose_graph(poses: F64, edges: list[tuple[int, int, Pose2D, F64]],
                        iterations: int = 10) -> F64:
    """Least-squares pose graph (node 0 fixed) by sparse Gauss–Newton.

    Args:
        poses: ``(N, 3)`` initial (x, y, yaw).
        edges: ``(i, j, z_ij, info)``: measured pose of j in i's frame, 3×3 information.

    Returns:
        The optimised ``(N, 3)`` poses.
    """
    x = poses.copy()
    n = len(x)
    if n < 2 or not edges:
        return x
    ii = np.array([e[0] for e in edges])
    jj = np.array([e[1] for e in edges])
    z = np.array([_v(e[2]) for e in edges])
    info = np.stack([e[3] for e in edges])
    m = len(edges)
    for _ in range(iterations):
        xi, xj = x[ii], x[jj]
        ci, si = np.cos(xi[:, 2]), np.sin(xi[:, 2])
        cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
        dx = xj[:, 0] - xi[:, 0]
        dy = xj[:, 1] - xi[:, 1]
        # d = R_i^T (t_j - t_i)
        d0 = ci * dx + si * dy
        d1 = -si * dx + ci * dy
        ex = cz * (d0 - z[:, 0]) + sz * (d1 - z[:, 1])
        ey = -sz * (d0 - z[:, 0]) + cz * (d1 - z[:, 1])
        et = wrap_angles(xj[:, 2] - xi[:, 2] - z[:, 2])
        e = np.stack([ex, ey, et], axis=1)
        # Jacobians (m, 3, 3).
        a = np.zeros((m, 3, 3))
        b = np.zeros((m, 3, 3))
        # R_z^T R_i^T
        r00 = cz * ci - sz * si
        r01 = cz * si + sz * ci
        r10 = -sz * ci + cz * (-si)
        r11 = -sz * si + cz * ci
        # d/dθ_i of R_i^T (t_j - t_i) = (-si*dx + ci*dy, -ci*dx - si*dy)
        g0 = d1
        g1 = -d0
        a[:, 0, 0], a[:, 0, 1] = -r00, -r01
        a[:, 1, 0], a[:, 1, 1] = -r10, -r11
        a[:, 0, 2] = cz * g0 + sz * g1
        a[:, 1, 2] = -sz * g0 + cz * g1
        a[:, 2, 2] = -1.0
        b[:, 0, 0], b[:, 0, 1] = r00, r01
        b[:, 1, 0], b[:, 1, 1] = r10, r11
        b[:, 2, 2] = 1.0
        at_o = np.einsum("mki,mkl->mil", a, info)
        bt_o = np.einsum("mki,mkl->mil", b, info)
        h_ii = np.einsum("mil,mlj->mij", at_o, a)
        h_ij = np.einsum("mil,mlj->mij", at_o, b)
        h_jj = np.einsum("mil,mlj->mij", bt_o, b)
        g_i = np.einsum("mil,ml->mi", at_o, e)
        g_j = np.einsum("mil,ml->mi", bt_o, e)
        rows: list[npt.NDArray[np.int64]] = []
        cols: list[npt.NDArray[np.int64]] = []
        vals: list[F64] = []
        r3 = np.arange(3)
        for blk, bi, bj in ((h_ii, ii, ii), (h_ij, ii, jj), (h_jj, jj, jj)):
            rr = (3 * bi)[:, None, None] + r3[None, :, None]
            cc = (3 * bj)[:, None, None] + r3[None, None, :]
            rows.append(np.broadcast_to(rr, blk.shape).ravel())
            cols.append(np.broadcast_to(cc, blk.shape).ravel())
            vals.append(blk.ravel())
            if blk is h_ij:
                rows.append(np.broadcast_to(cc, blk.shape).ravel())
                cols.append(np.broadcast_to(rr, blk.shape).ravel())
                vals.append(blk.ravel())
        h = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * n, 3 * n)).tocsr()
        g = np.zeros(3 * n)
        np.add.at(g, (3 * ii)[:, None] + r3[None, :], g_i)
        np.add.at(g, (3 * jj)[:, None] + r3[None, :], g_j)
        # Fix node 0.
        keep = np.arange(3, 3 * n)
        h_red = h[keep][:, keep] + sp.identity(3 * n - 3) * 1e-9
        step = spsolve(h_red.tocsc(), -g[keep])
        x[1:] += np.asarray(step).reshape(n - 1, 3)
        x[:, 2] = wrap_angles(x[:, 2])
        if float(np.max(np.abs(step))) < 1e-5:
            break
    return x


class ScanMapper:
    """Incremental mapper (see the module docstring)."""

    def __init__(self, params: MapperParams | None = None, initial: Pose2D = Pose2D()) -> None:
        self.p = params or MapperParams()
        self.grid = LogOdds(self.p.resolution_m, self.p)
        self.keyframes: list[Keyframe] = []
        self.loop_edges: list[tuple[int, int, Pose2D]] = []
        self.seq_edges: list[tuple[int, int, Pose2D]] = []
        self.pose = initial
        self._initial = initial
        self._last_odom: Pose2D | None = None
        self._field: DistanceField | None = None
        self._travel = 0.0
        self._cooldown = 0
        self.scans = 0
        self.matched = 0
        self.trajectory: list[tuple[float, Pose2D]] = []
        self._kf_scan_index: list[int] = []

    # --- per scan ------------------------------------------------------------------------------
    def add_scan(self, stamp: float, odom: Pose2D, points: F64, laser: Pose2D,
                 no_return_dirs: F64 | None = None) -> Pose2D:
        """Process one scan (``points`` in base_link) with its odometry; return the pose."""
        self.scans += 1
        delta = Pose2D()
        if self._last_odom is None:
            guess = self.pose
        else:
            delta = self._last_odom.inverse() @ odom
            self._travel += math.hypot(delta.x, delta.y)
            guess = self.pose @ delta
        self._last_odom = odom
        pose = guess
        prior: F64 | None = None
        f = self.p.odom_prior_fraction
        if f > 0.0 and self.scans > 1:
            trans, rot = math.hypot(delta.x, delta.y), abs(delta.yaw)
            sxy = 0.01 + f * trans
            syaw = 0.005 + f * rot + 0.5 * f * trans
            prior = np.diag([sxy**2, sxy**2, syaw**2])
        if self._field is not None and len(points) >= 20:
            pts = points
            if len(pts) > self.p.match_beams:
                pts = pts[np.linspace(0, len(pts) - 1, self.p.match_beams).astype(np.int64)]
            m = scan_match(self._field, pts, guess, iterations=20, max_residual_m=0.4,
                           inlier_m=0.1, surface_offset_m=0.0, prior_cov=prior)
            m = scan_match(self._field, pts, m.pose, iterations=15, max_residual_m=0.12,
                           inlier_m=0.08, surface_offset_m=0.0, prior_cov=prior,
                           prior_mean=guess)
            if m.inlier_fraction >= self.p.min_inlier_fraction and m.pose.distance_to(guess) < 0.6:
                pose = m.pose
                self.matched += 1
        self.pose = pose
        self.trajectory.append((stamp, pose))
        nr = no_return_dirs if no_return_dirs is not None else np.zeros((0, 2))
        last = self.keyframes[-1] if self.keyframes else None
        if last is None or self._is_keyframe(last.pose, pose):
            self._add_keyframe(pose, points, nr, laser)
        return pose

    def _is_keyframe(self, a: Pose2D, b: Pose2D) -> bool:
        return (a.distance_to(b) >= self.p.keyframe_d_m
                or abs(wrap_angle(a.yaw - b.yaw)) >= self.p.keyframe_a_rad)

    def _add_keyframe(self, pose: Pose2D, points: F64, no_return: F64, laser: Pose2D) -> None:
        kf = Keyframe(pose, points, no_return, laser, self._travel)
        self.keyframes.append(kf)
        self._kf_scan_index.append(len(self.trajectory) - 1)
        k = len(self.keyframes) - 1
        if k > 0:
            prev = self.keyframes[k - 1]
            self.seq_edges.append((k - 1, k, prev.pose.inverse() @ pose))
        self._integrate(kf)
        if self._cooldown > 0:
            self._cooldown -= 1
        elif k > 0 and k % self.p.loop_try_every == 0 and self._try_loop(k):
            self._optimize()
            self._cooldown = self.p.loop_cooldown
        self._field = DistanceField(self.grid.window(self.pose.x, self.pose.y, self.p.window_m),
                                    1.0)

    def _integrate(self, kf: Keyframe, grid: LogOdds | None = None) -> None:
        g = grid or self.grid
        ends = kf.pose.transform_points(kf.points)
        lo = kf.pose @ kf.laser
        clear = kf.pose.transform_points(kf.laser.transform_points(
            kf.no_return * self.p.no_return_clear_m)) if len(kf.no_return) else np.zeros((0, 2))
        g.integrate((lo.x, lo.y), ends, clear)

    # --- loop closure --------------------------------------------------------------------------
    def _try_loop(self, k: int) -> bool:
        cur = self.keyframes[k]
        best_j = -1
        best_d = self.p.loop_radius_m
        for j in range(k):
            kj = self.keyframes[j]
            if cur.travel_m - kj.travel_m < self.p.loop_min_travel_m:
                break
            d = kj.pose.distance_to(cur.pose)
            if d < best_d:
                best_d, best_j = d, j
        if best_j < 0:
            return False
        lo = max(0, best_j - self.p.loop_neighbours)
        hi = min(k, best_j + self.p.loop_neighbours + 1)
        sub = LogOdds(self.p.resolution_m, self.p)
        for kf in self.keyframes[lo:hi]:
            self._integrate(kf, sub)
        occ = sub.window(cur.pose.x, cur.pose.y, self.p.window_m)
        if not np.any(occ.data > 0):
            return False
        fld = DistanceField(occ, 1.0)
        pts = cur.points
        if len(pts) > 90:
            pts = pts[np.linspace(0, len(pts) - 1, 90).astype(np.int64)]
        cand = self._correlative(fld, pts, cur.pose)
        m = scan_match(fld, cur.points, cand, iterations=15, max_residual_m=0.3, inlier_m=0.1,
                       surface_offset_m=0.0)
        m = scan_match(fld, cur.points, m.pose, iterations=8, max_residual_m=0.12,
                       inlier_m=0.08, surface_offset_m=0.0)
        if m.inlier_fraction < self.p.loop_min_inliers:
            return False
        # Gate: the correction must be of the size scan-matching drift can reach over the
        # distance travelled since the old keyframe (a false match in a look-alike place jumps).
        travel = cur.travel_m - self.keyframes[best_j].travel_m
        shift = m.pose.distance_to(cur.pose)
        turn = abs(wrap_angle(m.pose.yaw - cur.pose.yaw))
        if (shift > 0.15 + self.p.loop_drift_fraction * travel
                or turn > 0.05 + self.p.loop_drift_rad_per_m * travel):
            log.debug("loop candidate %d -> %d rejected: shift %.2f m, turn %.3f rad", best_j, k,
                      shift, turn)
            return False
        z = self.keyframes[best_j].pose.inverse() @ m.pose
        self.loop_edges.append((best_j, k, z))
        log.info("loop closure: keyframe %d -> %d (correction %.2f m, fit %.2f)", best_j, k,
                 m.pose.distance_to(cur.pose), m.inlier_fraction)
        return True

    def _correlative(self, fld: DistanceField, pts: F64, guess: Pose2D) -> Pose2D:
        """Brute-force search of the best (x, y, yaw) offset around ``guess``."""
        step = 0.1
        n = round(self.p.loop_search_m / step)
        offs = np.arange(-n, n + 1) * step
        yaws = np.arange(-self.p.loop_search_rad, self.p.loop_search_rad + 1e-9, 0.035)
        best = (-1.0, guess)
        for dyaw in yaws:
            th = guess.yaw + dyaw
            c, s = math.cos(th), math.sin(th)
            rx = c * pts[:, 0] - s * pts[:, 1]
            ry = s * pts[:, 0] + c * pts[:, 1]
            gx = guess.x + offs[:, None, None] + rx[None, None, :]
            gy = guess.y + offs[None, :, None] + ry[None, None, :]
            gx, gy = np.broadcast_arrays(gx, gy)
            d = fld.lookup(gx, gy)
            score = np.mean(np.exp(-0.5 * (d / 0.15) ** 2), axis=2)
            i, j = np.unravel_index(int(np.argmax(score)), score.shape)
            if score[i, j] > best[0]:
                best = (float(score[i, j]), Pose2D(guess.x + offs[i], guess.y + offs[j], th))
        return best[1]

    def _optimize(self) -> None:
        info_odom = np.diag([1 / self.p.odom_sigma_xy_m**2, 1 / self.p.odom_sigma_xy_m**2,
                             1 / self.p.odom_sigma_yaw_rad**2])
        info_loop = np.diag([1 / self.p.loop_sigma_xy_m**2, 1 / self.p.loop_sigma_xy_m**2,
                             1 / self.p.loop_sigma_yaw_rad**2])
        edges = [(i, j, z, info_odom) for i, j, z in self.seq_edges]
        edges += [(i, j, z, info_loop) for i, j, z in self.loop_edges]
        x0 = np.array([_v(kf.pose) for kf in self.keyframes])
        x = optimize_pose_graph(x0, edges)
        last_old = self.keyframes[-1].pose
        for kf, row in zip(self.keyframes, x, strict=True):
            kf.pose = Pose2D(float(row[0]), float(row[1]), float(row[2]))
        self.pose = self.keyframes[-1].pose @ (last_old.inverse() @ self.pose)
        self._correct_trajectory(x0)
        # Rebuilding the grid is the expensive part: skip it when nothing moved visibly.
        shift = np.hypot(x[:, 0] - x0[:, 0], x[:, 1] - x0[:, 1]) + 3.0 * np.abs(
            wrap_angles(x[:, 2] - x0[:, 2]))
        if float(shift.max()) > 0.5 * self.p.resolution_m:
            self.rebuild()

    def _correct_trajectory(self, x0: F64) -> None:
        """Move every scan pose with the keyframe it follows."""
        idx = self._kf_scan_index
        for n, (k_start, k_end) in enumerate(zip(idx, [*idx[1:], len(self.trajectory)],
                                                 strict=True)):
            old = Pose2D(*x0[n])
            corr = self.keyframes[n].pose @ old.inverse()
            for t in range(k_start, k_end):
                stamp, p = self.trajectory[t]
                self.trajectory[t] = (stamp, corr @ p)

    def rebuild(self) -> None:
        """Rebuild the occupancy grid from every keyframe at its current pose."""
        self.grid = LogOdds(self.p.resolution_m, self.p)
        for kf in self.keyframes:
            self._integrate(kf)

    def occupancy(self) -> OccupancyGrid:
        """The map so far (cropped to what was seen)."""
        return self.grid.occupancy()


def _scan_inputs(s: LogScan, max_range_m: float) -> tuple[F64, F64]:
    pts = s.points(max_range_m)
    nr = ~np.isfinite(s.ranges_m)
    ang = s.angle_min_rad + np.flatnonzero(nr) * s.angle_increment_rad
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    return pts, dirs


def build_map_from_log(scans: Iterable[LogScan], params: MapperParams | None = None,
                       progress: Callable[[int], None] | None = None,
                       initial: Pose2D = Pose2D()) -> ScanMapper:
    """Run the mapper over the scans of a log; ``progress(n)`` after each scan."""
    mapper = ScanMapper(params, initial)
    for n, s in enumerate(scans, start=1):
        pts, dirs = _scan_inputs(s, min(s.range_max_m, mapper.p.max_range_m))
        mapper.add_scan(s.stamp, s.odom, pts, s.laser_pose, dirs)
        if progress is not None:
            progress(n)
    if mapper.loop_edges:
        mapper._optimize()
    return mapper


class MappingNode(MapOdomPublisher):
    """Online mapping while the rover is driven: ``SCAN`` + ``ODOM`` → ``POSE``, ``MAP``.

    Publishes the map every ``publish_period_s`` through ``on_map`` (the map server) and the
    pose (``map`` = the frame of the start pose) like the localiser does.
    """

    def __init__(self, bus: Bus, clock: Clock, laser: Pose2D, start: Pose2D,
                 on_map: Callable[[OccupancyGrid], None], params: MapperParams | None = None,
                 publish_period_s: float = 2.0) -> None:
        """Each scan is mapped through ``clock.offload``: a loop closure re-optimises the graph
        and rebuilds the grid, hundreds of milliseconds that must not block the event loop on
        a real clock (a worker thread); on a simulated clock scans are mapped inline, keeping
        runs deterministic."""
        from curio.core.pose_history import StampedHistory

        super().__init__(bus)
        self._inflight: asyncio.Future[tuple[Pose2D, OccupancyGrid | None]] | None = None
        self.clock = clock
        self.laser = laser
        self.mapper = ScanMapper(params, start)
        self.on_map = on_map
        self.publish_period_s = publish_period_s
        self._last_publish = -1e9
        self._odom: StampedHistory[Odometry] = StampedHistory(20)  # a scan takes the nearest

    def on_odom(self, odom: Odometry) -> None:
        """Buffer odometry and publish ``POSE`` = map→odom ∘ odom."""
        self._odom.add(odom.stamp, odom)
        super().on_odom(odom)

    def initial_pose(self) -> Pose2D:
        """The mapper's pose (the start)."""
        return self.mapper.pose

    def publish_status(self, stamp: float) -> None:
        """``LOCALIZATION``: ``ok`` (the map is being made around the rover)."""
        from curio.core.messages import LocalizationStatus
        from curio.core.topics import LOCALIZATION

        self.bus.publish(LOCALIZATION, LocalizationStatus(stamp, "ok"))

    def pose_covariance(self, odom: Odometry) -> tuple[float, ...]:
        """A fixed covariance (5 cm, 0.03 rad)."""
        return (0.0025, 0, 0, 0, 0.0025, 0, 0, 0, 0.001)

    def on_scan(self, scan: LaserScan) -> None:
        """Map one scan with the latest odometry."""
        odom = self._odom_for(scan)
        if odom is not None:
            self._after_scan(scan, odom, *self._map_scan(scan, odom))

    def _odom_for(self, scan: LaserScan) -> Odometry | None:
        return self._odom.nearest(scan.stamp)

    def _map_scan(self, scan: LaserScan, odom: Odometry) -> tuple[Pose2D, OccupancyGrid | None]:
        """The heavy part (thread-safe off the loop: touches the mapper only): the scan's pose
        and, when a publication is due, the map."""
        r = np.asarray(scan.ranges_m, dtype=np.float64)
        s = LogScan(scan.stamp, odom.pose, self.laser, scan.angle_min_rad,
                    scan.angle_increment_rad, np.where(scan.valid_mask(), r, np.inf),
                    scan.range_max_m)
        pts, dirs = _scan_inputs(s, min(scan.range_max_m, self.mapper.p.max_range_m))
        pose = self.mapper.add_scan(scan.stamp, odom.pose, pts, self.laser, dirs)
        grid = None
        if scan.stamp - self._last_publish >= self.publish_period_s:
            grid = self.mapper.occupancy()
        return pose, grid

    def _after_scan(self, scan: LaserScan, odom: Odometry, pose: Pose2D,
                    grid: OccupancyGrid | None) -> None:
        """Publish the correction and the map (on the loop)."""
        self.set_correction(pose, odom.pose, scan.stamp)
        if grid is not None:
            self._last_publish = scan.stamp
            self.on_map(grid)

    async def finish(self) -> OccupancyGrid | None:
        """After ``run`` ends: wait for a scan still being mapped, close the pending loops and
        return the final map (None if nothing was mapped); heavy work through
        ``clock.offload``."""
        if self._inflight is not None:
            await asyncio.wait([self._inflight])
        mapper = self.mapper
        if not mapper.keyframes:
            return None

        def final() -> OccupancyGrid:
            if mapper.loop_edges:
                mapper._optimize()
            return mapper.occupancy()

        return await self.clock.offload(final)

    async def run(self) -> None:
        """Consume odometry and scans until cancelled."""
        from curio.core.topics import ODOM, SCAN

        odom_sub = self.bus.subscribe(ODOM, maxsize=64)
        scan_sub = self.bus.subscribe(SCAN, maxsize=1)

        async def odometry() -> None:
            async for o in odom_sub:
                self.on_odom(o)

        async def scans() -> None:
            async for s in scan_sub:
                for o in odom_sub.drain():
                    self.on_odom(o)
                odom = self._odom_for(s)
                if odom is not None:
                    self._inflight = self.clock.offload(self._map_scan, s, odom)
                    # Shielded: a cancelled run leaves the thread to finish (see ``finish``).
                    pose, grid = await asyncio.shield(self._inflight)
                    self._after_scan(s, odom, pose, grid)

        try:
            await asyncio.gather(odometry(), scans())
        finally:
            odom_sub.close()
            scan_sub.close()
