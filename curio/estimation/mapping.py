"""Mapping a new building: scan-to-map matching, a pose graph of keyframes, verified loop closures.

:class:`ScanMapper` is the engine (no bus, no clock), fed with scans and the odometry at each
scan — online by :class:`MappingNode` (``SCAN`` + ``ODOM`` while the rover is driven) and offline
by :func:`build_map_from_log` (``curio map build``).

Per scan (the *front end*):

1. **Prediction** from odometry: the last pose composed with the odometry increment.
2. **Correlative search** (:mod:`curio.estimation.scan_matching`): the scan is placed on a
   likelihood grid of the *local map* — the points of the keyframes of the last
   ``local_map_m`` of driving — by an exact branch-and-bound search over ``±search_xy_m`` and
   ``±search_rad`` around the prediction (twice that when nothing fits: wheel slip, a jump of
   the odometry). Odometry headings on real robots are often off by 10–20° after a quick turn;
   a local refinement alone, started there, slides into the wrong basin.
3. **Refinement**: point-to-line ICP on the local map's points and normals, as a maximum a
   posteriori estimate with the odometry increment as a Gaussian prior (σ growing with the
   distance and the turn). Its information matrix says which directions the scan fixed: in a
   featureless corridor the position along the axis is left to the odometry, and the pose graph
   is told so. A match whose inliers fall below ``min_inlier_fraction`` is not used (the
   odometry guess is, with the odometry's information).
4. **Keyframes** every ``keyframe_d_m`` / ``keyframe_a_rad`` of motion become pose-graph nodes,
   linked to the previous keyframe by the matched relative pose and its information; every scan
   keeps its pose relative to its keyframe, so it follows the keyframe when the graph moves.

The *back end* (:mod:`curio.estimation.loop_closure`, :mod:`curio.estimation.pose_graph`):
keyframes are grouped into submaps; new keyframes are matched on old submaps within a radius
that grows with the distance driven since; matches become loop-closure edges only when several
agree with each other (or with an estimate that a recent closure already corrected); the graph
is optimised with robust (dynamic covariance scaling) loop edges and edges that still disagree
afterwards are dropped. The occupancy grid (log odds) is rebuilt from the keyframes at their
optimised poses.

Frames: the map is built in the frame of the first pose (``initial`` pose, default the origin;
the first keyframe is the graph's fixed node, so the frame does not drift); odometry is
``base_link`` in ``odom``; scan points are in ``base_link``. Metres and radians.
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

from curio.core.geometry import Pose2D, wrap_angle
from curio.estimation.carmen import LogScan
from curio.estimation.correction import MapOdomPublisher
from curio.estimation.log_odds_kernel import integrate_rays
from curio.estimation.loop_closure import Keyframe, LoopCloser, LoopParams
from curio.estimation.maps import OccupancyGrid
from curio.estimation.pose_graph import PoseGraph, to_local_info
from curio.estimation.scan_matching import (
    LikelihoodGrid,
    PointMap,
    Refined,
    refine,
    scan_normals,
    voxel_subsample,
)

if TYPE_CHECKING:
    from curio.core.bus import Bus
    from curio.core.clock import Clock
    from curio.core.messages import LaserScan, Odometry

__all__ = [
    "Keyframe",
    "MapDrawer",
    "MapSnapshot",
    "MapperParams",
    "MappingNode",
    "ScanMapper",
    "build_map_from_log",
    "optimize_pose_graph",
]

log = logging.getLogger("curio.estimation.mapping")

F64 = npt.NDArray[np.float64]


@dataclass
class MapperParams(LoopParams):
    """Tuning of :class:`ScanMapper` (defaults suit a 360° 12 m lidar or a 180° SICK).

    Loop-closure fields are those of :class:`curio.estimation.loop_closure.LoopParams`.
    """

    resolution_m: float = 0.05
    max_range_m: float = 12.0
    no_return_clear_m: float = 3.0
    l_occ: float = 0.9
    l_free: float = -0.4
    l_max: float = 6.0
    keyframe_d_m: float = 0.3
    keyframe_a_rad: float = 0.2
    local_map_m: float = 8.0
    local_map_keyframes: int = 40
    match_cell_m: float = 0.05
    search_xy_m: float = 0.4
    search_rad: float = 0.45
    search_step_rad: float = math.radians(0.5)
    min_match_score: float = 0.25
    min_inlier_fraction: float = 0.35
    odom_sigma_xy_m: float = 0.01
    odom_xy_per_m: float = 0.2
    odom_sigma_yaw_rad: float = 0.005
    odom_yaw_per_rad: float = 0.3
    odom_yaw_per_m: float = 0.1
    dcs_phi: float = 5.0
    outlier_chi2: float = 30.0
    optimize_every: int = 8


def optimize_pose_graph(poses: F64, edges: list[tuple[int, int, Pose2D, F64]],
                        iterations: int = 20) -> F64:
    """Least-squares pose graph (node 0 fixed): a thin wrapper of
    :class:`curio.estimation.pose_graph.PoseGraph` without robust edges.

    Args:
        poses: ``(N, 3)`` initial (x, y, yaw) in ``map``.
        edges: ``(i, j, z_ij, info)``: measured pose of j in i's frame, 3×3 information.

    Returns:
        The optimised ``(N, 3)`` poses.
    """
    g = PoseGraph()
    for row in poses:
        g.add_node(Pose2D(float(row[0]), float(row[1]), float(row[2])))
    for i, j, z, info in edges:
        g.add_edge(i, j, z, info)
    g.optimize(iterations)
    return g.poses


class LogOdds:
    """A growing log-odds grid; cell (0, 0)'s corner at ``origin`` (no rotation)."""

    def __init__(self, resolution_m: float, params: MapperParams) -> None:
        self.res = resolution_m
        self.p = params
        self.l: npt.NDArray[np.float32] = np.zeros((0, 0), dtype=np.float32)
        self.seen: npt.NDArray[np.bool_] = np.zeros((0, 0), dtype=bool)
        self._mark: npt.NDArray[np.int64] = np.zeros((0, 0), dtype=np.int64)
        self._scan_id = 0
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
            self._mark = np.zeros((h, w), dtype=np.int64)
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
            self._mark = np.pad(self._mark, ((gb, gt), (gl, gr)))
            self.ox -= gl * res
            self.oy -= gb * res

    def integrate(self, origin_xy: tuple[float, float], ends: F64, clear_ends: F64) -> None:
        """One scan: rays from ``origin_xy`` to ``ends`` (hit) and to ``clear_ends`` (no hit).

        Free cells are sampled every 0.8 cell up to one cell short of a hit (to the end if
        none); a cell that is some beam's end point in this scan is not also marked free; each
        cell is updated at most once per scan (:mod:`curio.estimation.log_odds_kernel`).
        """
        allp = np.vstack([ends, clear_ends, np.array([origin_xy])])
        self._ensure(float(allp[:, 0].min()), float(allp[:, 1].min()),
                     float(allp[:, 0].max()), float(allp[:, 1].max()))
        targets = np.ascontiguousarray(np.vstack([ends, clear_ends]), dtype=np.float64)
        if len(targets) == 0:
            return
        self._scan_id += 1
        integrate_rays(self.l, self.seen, self._mark, self._scan_id, self.ox, self.oy, self.res,
                       float(origin_xy[0]), float(origin_xy[1]), targets, len(ends),
                       self.p.l_free, self.p.l_occ, self.p.l_max)

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


class ScanMapper:
    """Incremental mapper (see the module docstring)."""

    def __init__(self, params: MapperParams | None = None, initial: Pose2D = Pose2D()) -> None:
        self.p = params or MapperParams()
        self.drawer = MapDrawer(self.p)
        self.graph = PoseGraph(self.p.dcs_phi)
        self.keyframes: list[Keyframe] = []
        self.loops = LoopCloser(self.p, self.keyframes, self.graph)
        self.pose = initial
        self._last_odom: Pose2D | None = None
        self._since_kf = Pose2D()
        self._travel = 0.0
        self.scans = 0
        self.matched = 0
        self.optimizations = 0
        self._unoptimized = 0
        self.version = 0  # bumped whenever keyframes move (an optimisation)
        self._local: tuple[PointMap, LikelihoodGrid] | None = None
        self._traj: list[tuple[float, int, Pose2D]] = []  # stamp, keyframe, pose in its frame

    # --- results -------------------------------------------------------------------------------
    @property
    def trajectory(self) -> list[tuple[float, Pose2D]]:
        """Every scan's stamp and pose in ``map`` (following the optimised keyframes)."""
        return [(t, self.keyframes[k].pose @ rel) for t, k, rel in self._traj]

    @property
    def loop_edges(self) -> list[tuple[int, int, Pose2D]]:
        """Active loop-closure constraints ``(old keyframe, new keyframe, new in old's frame)``."""
        g = self.graph
        return [(g.ii[e], g.jj[e], Pose2D(*g.z[e])) for e, _ in self.loops.accepted
                if g.active[e]]

    @property
    def _kf_scan_index(self) -> list[int]:
        return [kf.scan_index for kf in self.keyframes]

    # --- per scan ------------------------------------------------------------------------------
    def add_scan(self, stamp: float, odom: Pose2D, points: F64, laser: Pose2D,
                 no_return_dirs: F64 | None = None) -> Pose2D:
        """Process one scan (``points`` in base_link, beam order) with its odometry pose
        (``base_link`` in ``odom``); return the scan's pose in ``map``."""
        self.scans += 1
        delta = Pose2D() if self._last_odom is None else self._last_odom.inverse() @ odom
        self._last_odom = odom
        self._travel += math.hypot(delta.x, delta.y)
        self._since_kf = self._since_kf @ delta
        guess = self.pose @ delta
        pose, info = guess, None
        if self._local is not None and len(points) >= 10:
            ref = self._match(points, guess, delta)
            if ref is not None:
                pose, info = ref.pose, ref.info_total
                self.matched += 1
        self.pose = pose
        last = self.keyframes[-1] if self.keyframes else None
        if last is None or self._is_keyframe(last.pose, pose):
            nr = no_return_dirs if no_return_dirs is not None else np.zeros((0, 2))
            self._add_keyframe(stamp, pose, points, nr, laser, info)
        else:
            k = len(self.keyframes) - 1
            self._traj.append((stamp, k, last.pose.inverse() @ pose))
        return self.pose

    def _is_keyframe(self, a: Pose2D, b: Pose2D) -> bool:
        return (a.distance_to(b) >= self.p.keyframe_d_m
                or abs(wrap_angle(a.yaw - b.yaw)) >= self.p.keyframe_a_rad)

    def _odom_info(self, delta: Pose2D) -> F64:
        """Information (1/m², 1/rad²) of an odometry increment, isotropic in x and y."""
        p = self.p
        trans, rot = math.hypot(delta.x, delta.y), abs(delta.yaw)
        sxy = p.odom_sigma_xy_m + p.odom_xy_per_m * trans
        syaw = p.odom_sigma_yaw_rad + p.odom_yaw_per_rad * rot + p.odom_yaw_per_m * trans
        return np.diag([1.0 / sxy**2, 1.0 / sxy**2, 1.0 / syaw**2])

    def _near(self, points: F64) -> F64:
        return points[np.hypot(points[:, 0], points[:, 1]) <= self.p.match_range_m]

    def _match(self, points: F64, guess: Pose2D, delta: Pose2D) -> Refined | None:
        """Scan-to-local-map: correlative search, then MAP point-to-line refinement."""
        assert self._local is not None
        pmap, lgrid = self._local
        near = self._near(points)
        if len(near) < 10:
            return None
        sub = near[voxel_subsample(near, 0.1)]
        p = self.p
        found = lgrid.search(sub, guess, p.search_xy_m, p.search_rad, p.search_step_rad,
                             p.min_match_score)
        if found is None:
            found = lgrid.search(sub, guess, 2.0 * p.search_xy_m, 2.0 * p.search_rad,
                                 2.0 * p.search_step_rad, p.min_match_score)
            if found is None:
                return None
        ref = refine(pmap, near, found[0], sigma_m=p.match_sigma_m, prior_mean=guess,
                     prior_info=self._odom_info(delta))
        if ref.inlier_fraction < p.min_inlier_fraction:
            return None
        return ref

    # --- keyframes -----------------------------------------------------------------------------
    def _add_keyframe(self, stamp: float, pose: Pose2D, points: F64, no_return: F64,
                      laser: Pose2D, info_map: F64 | None) -> None:
        normals, ok = scan_normals(points)
        kf = Keyframe(pose, points, normals, ok, no_return, laser, self._travel, len(self._traj))
        k = self.graph.add_node(pose)
        self.keyframes.append(kf)
        self._traj.append((stamp, k, Pose2D()))
        if k > 0:
            prev = self.keyframes[k - 1]
            info = info_map if info_map is not None else self._odom_info(self._since_kf)
            self.graph.add_edge(k - 1, k, prev.pose.inverse() @ pose,
                                to_local_info(info, pose.yaw))
        self._since_kf = Pose2D()
        edges = self.loops.on_keyframe(lambda: self._query_cloud(k))
        if edges:
            # A loop into a new region moves the graph far: optimise at once. Further closures
            # in a region the estimate already agrees with are batched.
            self._unoptimized += len(edges)
            if self.loops.new_region or self._unoptimized >= self.p.optimize_every:
                self._optimize()
        self._rebuild_local()

    def _query_cloud(self, k: int) -> F64:
        """Points of keyframe ``k`` and its neighbours of the last ``loop_query_m``, in k's
        ``base_link``, thinned to one per 5 cm."""
        cur = self.keyframes[k]
        inv = cur.pose.inverse()
        pts = [self._near(cur.points)]
        j = k - 1
        while j >= 0 and cur.travel_m - self.keyframes[j].travel_m <= self.p.loop_query_m:
            kf = self.keyframes[j]
            pts.append((inv @ kf.pose).transform_points(self._near(kf.points)))
            j -= 1
        allp = np.vstack(pts)
        return allp[voxel_subsample(allp, 0.05)]

    def _rebuild_local(self) -> None:
        """The local map: keyframes of the last ``local_map_m`` of driving, in ``map``."""
        kfs = self.keyframes
        last = kfs[-1]
        pts: list[F64] = []
        nrm: list[F64] = []
        ok: list[npt.NDArray[np.bool_]] = []
        for kf in reversed(kfs):
            if (last.travel_m - kf.travel_m > self.p.local_map_m
                    or len(pts) >= self.p.local_map_keyframes):
                break
            near = np.hypot(kf.points[:, 0], kf.points[:, 1]) <= self.p.match_range_m
            pts.append(kf.pose.transform_points(kf.points[near]))
            c, s = math.cos(kf.pose.yaw), math.sin(kf.pose.yaw)
            n = kf.normals[near]
            nrm.append(np.stack([c * n[:, 0] - s * n[:, 1], s * n[:, 0] + c * n[:, 1]], axis=1))
            ok.append(kf.normal_ok[near])
        allp = np.vstack(pts)
        keep = voxel_subsample(allp, 0.02)
        allp = allp[keep]
        good = np.concatenate(ok)[keep]
        pmap = PointMap(allp[good], np.vstack(nrm)[keep][good])
        reach = self.p.match_range_m + 2.0 * self.p.search_xy_m
        x, y = self.pose.x, self.pose.y
        grid = LikelihoodGrid(allp, self.p.match_cell_m, self.p.match_cell_m, 3,
                              bounds=(x - reach, y - reach, x + reach, y + reach))
        self._local = (pmap, grid)

    # --- back end ------------------------------------------------------------------------------
    def _optimize(self) -> None:
        """Optimise the graph (plain least squares, then drop the loop edges that still
        disagree, then with the robust kernel), and move everything along."""
        self.graph.optimize(robust=False)
        for _ in range(5):
            chi2 = self.graph.chi2()
            out = self.graph.outliers(self.p.outlier_chi2)
            if not out:
                break
            worst = max(out, key=lambda e: chi2[e])  # one at a time: it may explain the rest
            self.graph.deactivate(worst)
            log.info("loop closure %d -> %d dropped after optimisation (chi2 %.1f)",
                     self.graph.ii[worst], self.graph.jj[worst], float(chi2[worst]))
            self.graph.optimize(robust=False)
        self.graph.optimize()
        self.optimizations += 1
        self._unoptimized = 0
        last = self.keyframes[-1]
        rel = last.pose.inverse() @ self.pose
        x = self.graph.poses
        for kf, row in zip(self.keyframes, x, strict=True):
            kf.pose = Pose2D(float(row[0]), float(row[1]), float(row[2]))
        self.pose = last.pose @ rel
        self.loops.invalidate()
        self.version += 1

    def finish(self) -> None:
        """After the last scan: a final optimisation if there are loop closures."""
        if self.loop_edges:
            self._optimize()

    # --- the occupancy grid --------------------------------------------------------------------
    def snapshot(self) -> MapSnapshot:
        """What the map is drawn from, as it is now (cheap; safe to draw in another thread)."""
        return MapSnapshot(self.version, tuple((kf.pose, kf) for kf in self.keyframes))

    @property
    def grid(self) -> LogOdds:
        """The log-odds grid as last drawn."""
        return self.drawer.grid

    def rebuild(self) -> None:
        """Redraw the occupancy grid from every keyframe at its current pose."""
        self.drawer.draw(self.snapshot(), full=True)

    def occupancy(self) -> OccupancyGrid:
        """The map so far (cropped to what was seen); redrawn first if the graph moved."""
        return self.drawer.draw(self.snapshot())


@dataclass(frozen=True)
class MapSnapshot:
    """The keyframes to draw, with the poses they had at ``version`` of the mapper's graph."""

    version: int
    keyframes: tuple[tuple[Pose2D, Keyframe], ...]


class MapDrawer:
    """Draws (and keeps) the log-odds grid of a :class:`MapSnapshot`: only the new keyframes
    when the graph has not moved since the last drawing, all of them when it has."""

    def __init__(self, params: MapperParams) -> None:
        self.p = params
        self.grid = LogOdds(params.resolution_m, params)
        self._version = -1
        self._count = 0

    def _integrate(self, pose: Pose2D, kf: Keyframe) -> None:
        ends = pose.transform_points(kf.points)
        lo = pose @ kf.laser
        clear = (pose.transform_points(kf.laser.transform_points(
            kf.no_return * self.p.no_return_clear_m)) if len(kf.no_return)
            else np.zeros((0, 2)))
        self.grid.integrate((lo.x, lo.y), ends, clear)

    def draw(self, snap: MapSnapshot, full: bool = False) -> OccupancyGrid:
        """Bring the grid up to ``snap`` and return it as map_server occupancy."""
        if full or snap.version != self._version or len(snap.keyframes) < self._count:
            self.grid = LogOdds(self.p.resolution_m, self.p)
            self._count = 0
            self._version = snap.version
        for pose, kf in snap.keyframes[self._count:]:
            self._integrate(pose, kf)
        self._count = len(snap.keyframes)
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
    mapper.finish()
    return mapper


class MappingNode(MapOdomPublisher):
    """Online mapping while the rover is driven: ``SCAN`` + ``ODOM`` → ``POSE``, ``MAP``.

    Publishes the map every ``publish_period_s`` through ``on_map`` (the map server) and the
    pose (``map`` = the frame of the start pose) like the localiser does.
    """

    def __init__(self, bus: Bus, clock: Clock, laser: Pose2D, start: Pose2D,
                 on_map: Callable[[OccupancyGrid], None], params: MapperParams | None = None,
                 publish_period_s: float = 2.0) -> None:
        """Each scan is mapped, and the published map drawn, through ``clock.offload``: a loop
        closure re-optimises the graph (tens of milliseconds) and the map must then be redrawn
        from every keyframe (hundreds), neither of which may block the event loop on a real
        clock (worker threads), and the drawing must not hold up the next scan; on a simulated
        clock both run inline, keeping runs deterministic."""
        from curio.core.pose_history import StampedHistory

        super().__init__(bus)
        self._inflight: asyncio.Future[tuple[Pose2D, MapSnapshot | None]] | None = None
        self._drawing: asyncio.Future[OccupancyGrid] | None = None
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

    def _map_scan(self, scan: LaserScan, odom: Odometry) -> tuple[Pose2D, MapSnapshot | None]:
        """The heavy part (thread-safe off the loop: touches the mapper only): the scan's pose
        and, when a publication is due, what to draw."""
        r = np.asarray(scan.ranges_m, dtype=np.float64)
        s = LogScan(scan.stamp, odom.pose, self.laser, scan.angle_min_rad,
                    scan.angle_increment_rad, np.where(scan.valid_mask(), r, np.inf),
                    scan.range_max_m)
        pts, dirs = _scan_inputs(s, min(scan.range_max_m, self.mapper.p.max_range_m))
        pose = self.mapper.add_scan(scan.stamp, odom.pose, pts, self.laser, dirs)
        snap = None
        if scan.stamp - self._last_publish >= self.publish_period_s:
            snap = self.mapper.snapshot()
        return pose, snap

    def _after_scan(self, scan: LaserScan, odom: Odometry, pose: Pose2D,
                    snap: MapSnapshot | None) -> None:
        """Publish the correction (on the loop) and start drawing the map if one is due."""
        self.set_correction(pose, odom.pose, scan.stamp)
        if snap is not None and self._draw(snap):
            self._last_publish = scan.stamp

    def _draw(self, snap: MapSnapshot) -> bool:
        """Draw and publish ``snap``; False if the previous drawing is still running."""
        if self._drawing is not None and not self._drawing.done():
            return False
        self._drawing = self.clock.offload(self.mapper.drawer.draw, snap)
        if self._drawing.done():  # drawn inline (simulated clock): publish now, in order
            self._drawn(self._drawing)
        else:
            self._drawing.add_done_callback(self._drawn)
        return True

    def _drawn(self, fut: asyncio.Future[OccupancyGrid]) -> None:
        if fut.cancelled():
            return
        exc = fut.exception()
        if exc is not None:
            log.error("drawing the map failed: %r", exc)
            return
        self.on_map(fut.result())

    async def finish(self) -> OccupancyGrid | None:
        """After ``run`` ends: wait for a scan still being mapped and a map being drawn, close
        the pending loops and return the final map (None if nothing was mapped); heavy work
        through ``clock.offload``."""
        pending = [f for f in (self._inflight, self._drawing) if f is not None]
        if pending:
            await asyncio.wait(pending)
        mapper = self.mapper
        if not mapper.keyframes:
            return None

        def final() -> OccupancyGrid:
            mapper.finish()
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
                    pose, snap = await asyncio.shield(self._inflight)
                    self._after_scan(s, odom, pose, snap)

        try:
            await asyncio.gather(odometry(), scans())
        finally:
            odom_sub.close()
            scan_sub.close()
