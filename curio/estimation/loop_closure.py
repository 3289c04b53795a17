"""Loop closure for the mapper: submaps, candidate search, and verification before a constraint
reaches the pose graph.

How a closure is found (the pattern of Cartographer's constraint builder and Karto's loop
search, in our own terms):

1. **Submaps.** Keyframes are grouped, in driving order, into submaps of ``submap_m`` of travel.
   A finished submap keeps its keyframes' points and normals in the frame of its middle
   keyframe (the *anchor*), so it moves rigidly with that node when the graph is re-optimised.
2. **Candidates.** At every ``loop_try_every``-th keyframe, finished submaps at least
   ``loop_min_travel_m`` of driving back whose keyframes pass within the search radius of the
   current pose are candidates, nearest first. The radius grows with the distance driven since
   (``loop_radius_m + loop_radius_per_m × travel``, at most ``loop_max_radius_m``): drift is
   what a loop closure has to undo.
3. **Matching.** The current keyframe and its recent neighbours (a wider view than one
   scan — decisive in corridors and with a 180° laser) are matched on the submap by the
   branch-and-bound correlative search over the whole radius and ``±loop_search_rad``, then
   refined by point-to-line ICP; the match must reach ``loop_min_score`` and
   ``loop_min_inliers``. The ICP information matrix is the constraint's information: a
   corridor match constrains across the corridor and the heading, hardly along it. A second
   search for the runner-up outside the best peak (``loop_peak_m``, ``loop_peak_rad``) tells
   a unique match from an ambiguous one: a runner-up scoring ``loop_ambiguity`` of the best at
   another heading rejects the match; at the same heading (a corridor, a row of identical
   doors) the constraint keeps no information along the line joining the two peaks.
4. **Verification.** A match is a *hypothesis*, not yet a constraint:

   * closing a loop into a region not recently connected needs ``loop_consistent``
     hypotheses (from different keyframes) that agree with each other: chained with the
     trajectory between them they must form a cycle that closes within their covariances
     plus a tolerance that grows with the length of the chains (pairwise consistency, as in
     Olson's single-cluster graph partitioning). One look-alike match never closes a loop on
     its own;
   * while the trajectory stays in a region it has just been connected to, a hypothesis is
     accepted when it agrees with the current (optimised) estimate within the same
     Mahalanobis gate.

   The pose graph's robust kernel (:mod:`curio.estimation.pose_graph`) and the removal of
   edges whose χ² stays large after optimisation catch what gets past these checks.

Frames: keyframe poses are ``base_link`` in ``map``; submap points are in the anchor's
``base_link`` frame. Metres, radians.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, wrap_angle
from curio.estimation.pose_graph import PoseGraph, adjoint, to_local_info
from curio.estimation.scan_matching import (
    LikelihoodGrid,
    PointMap,
    refine,
    voxel_subsample,
)

__all__ = ["Hypothesis", "Keyframe", "LoopCloser", "LoopParams", "Submap"]

log = logging.getLogger("curio.estimation.mapping")

F64 = npt.NDArray[np.float64]


@dataclass
class Keyframe:
    """A scan kept in the map (a pose-graph node).

    Attributes:
        pose: ``base_link`` in ``map`` (kept in step with the graph).
        points: ``(N, 2)`` end points in ``base_link``, beam order.
        normals: ``(N, 2)`` their unit normals in ``base_link``.
        normal_ok: ``(N,)`` whether each normal is trustworthy.
        no_return: ``(M, 2)`` unit directions (``laser`` frame) of beams without a return.
        laser: ``laser`` in ``base_link``.
        travel_m: odometry distance driven from the start to this keyframe.
        scan_index: index of the scan in the mapper's trajectory.
    """

    pose: Pose2D
    points: F64
    normals: F64
    normal_ok: npt.NDArray[np.bool_]
    no_return: F64
    laser: Pose2D
    travel_m: float
    scan_index: int


@dataclass
class LoopParams:
    """Tuning of loop closure (see the module docstring; metres, radians)."""

    submap_m: float = 5.0
    loop_min_travel_m: float = 10.0
    loop_radius_m: float = 2.0
    loop_radius_per_m: float = 0.03
    loop_max_radius_m: float = 8.0
    loop_search_rad: float = 0.5
    loop_step_rad: float = math.radians(1.0)
    loop_cell_m: float = 0.05
    loop_min_score: float = 0.5
    loop_min_inliers: float = 0.55
    loop_ambiguity: float = 0.9
    loop_peak_m: float = 0.3
    loop_peak_rad: float = math.radians(3.0)
    loop_try_every: int = 2
    loop_candidates: int = 2
    loop_query_m: float = 1.5
    loop_consistent: int = 2
    loop_pending_m: float = 8.0
    loop_connected_m: float = 5.0
    loop_tol_m: float = 0.1
    loop_tol_rad: float = 0.02
    loop_tol_per_m: float = 0.01
    loop_gate_chi2: float = 11.3  # χ²(3 dof), 99 %
    match_sigma_m: float = 0.05
    match_range_m: float = 15.0
    grid_cache: int = 4


@dataclass
class Submap:
    """Keyframes ``first..last`` (inclusive) held rigidly in the frame of ``anchor``."""

    first: int
    last: int
    anchor: int
    points: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    normals: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    pmap: PointMap | None = None


@dataclass(frozen=True)
class Hypothesis:
    """A loop closure found by matching, not yet accepted: keyframe ``kf`` at ``z`` in
    ``anchor``'s frame, with information ``info`` (3×3, in ``z``'s own frame, the pose graph's
    edge convention)."""

    anchor: int
    kf: int
    z: Pose2D
    info: F64
    score: float
    inliers: float


def _cov(info: F64) -> F64:
    """Covariance of an information matrix, unbounded directions capped at (10 m)², 1 rad²."""
    return np.asarray(np.linalg.inv(info + np.diag([1e-2, 1e-2, 1.0])), dtype=np.float64)


def _err(a: Pose2D, b: Pose2D) -> F64:
    d = a.inverse() @ b
    return np.array([d.x, d.y, d.yaw])


class LoopCloser:
    """Finds, verifies and adds loop-closure edges (see the module docstring).

    Args:
        params: the tuning.
        keyframes: the mapper's keyframe list (shared, read only here).
        graph: the mapper's pose graph (edges are added to it).
    """

    def __init__(self, params: LoopParams, keyframes: list[Keyframe], graph: PoseGraph) -> None:
        self.p = params
        self.kfs = keyframes
        self.graph = graph
        self.submaps: list[Submap] = []
        self._open_first = 0
        self._grids: OrderedDict[int, LikelihoodGrid] = OrderedDict()
        self.pending: list[Hypothesis] = []
        self.accepted: list[tuple[int, Hypothesis]] = []  # (edge index, hypothesis)
        self._connected = (-math.inf, -math.inf)  # travel of the last closure's kf and anchor
        self.tried = 0
        self.matched = 0
        self.rejected_inconsistent = 0
        self.ambiguous = 0
        self.new_region = False  # the last edges closed a loop into a region not connected

    # --- submaps -------------------------------------------------------------------------------
    def _close_submaps(self) -> None:
        k = len(self.kfs) - 1
        first = self._open_first
        if k - first < 2 or self.kfs[k].travel_m - self.kfs[first].travel_m < self.p.submap_m:
            return
        self.submaps.append(Submap(first, k, (first + k) // 2))
        self._open_first = k + 1

    def _submap_cloud(self, s: Submap) -> Submap:
        if s.pmap is not None:
            return s
        anchor_inv = self.kfs[s.anchor].pose.inverse()
        pts, nrm, ok = [], [], []
        for kf in self.kfs[s.first:s.last + 1]:
            rel = anchor_inv @ kf.pose
            near = np.hypot(kf.points[:, 0], kf.points[:, 1]) <= self.p.match_range_m
            pts.append(rel.transform_points(kf.points[near]))
            c, sn = math.cos(rel.yaw), math.sin(rel.yaw)
            n = kf.normals[near]
            nrm.append(np.stack([c * n[:, 0] - sn * n[:, 1], sn * n[:, 0] + c * n[:, 1]], axis=1))
            ok.append(kf.normal_ok[near])
        allp = np.vstack(pts)
        alln = np.vstack(nrm)
        allok = np.concatenate(ok)
        keep = voxel_subsample(allp, 0.02)
        s.points = allp[keep]
        s.normals = alln[keep]
        good = allok[keep]
        s.pmap = PointMap(s.points[good], s.normals[good])
        return s

    def _grid(self, idx: int) -> LikelihoodGrid:
        g = self._grids.get(idx)
        if g is not None:
            self._grids.move_to_end(idx)
            return g
        s = self._submap_cloud(self.submaps[idx])
        cells = self.p.loop_max_radius_m / self.p.loop_cell_m
        depth = max(1, math.ceil(math.log2(max(2.0, 2 * cells + 1))) - 1)
        g = LikelihoodGrid(s.points, self.p.loop_cell_m, self.p.loop_cell_m, depth)
        self._grids[idx] = g
        while len(self._grids) > self.p.grid_cache:
            self._grids.popitem(last=False)
        return g

    def invalidate(self) -> None:
        """The graph moved: rebuild submap clouds and grids when next needed."""
        for s in self.submaps:
            s.pmap = None
        self._grids.clear()

    # --- per keyframe --------------------------------------------------------------------------
    def on_keyframe(self, query: Callable[[], F64]) -> list[int]:
        """Search, match and verify for the newest keyframe; return the edges added.

        Args:
            query: gives the ``(N, 2)`` points of the newest keyframe and its recent
                neighbours in the newest keyframe's ``base_link`` frame (called only when a
                candidate is tried).
        """
        self._close_submaps()
        k = len(self.kfs) - 1
        self.new_region = False
        if k % self.p.loop_try_every != 0 or not self.submaps:
            return []
        added: list[int] = []
        points: F64 | None = None
        for idx in self._candidates(k):
            points = query() if points is None else points
            hyp = self._match(idx, k, points)
            if hyp is None:
                continue
            added += self._verify(hyp)
            if added:
                break
        return added

    def _candidates(self, k: int) -> list[int]:
        cur = self.kfs[k]
        poses = np.array([[f.pose.x, f.pose.y] for f in self.kfs[:k]])
        out: list[tuple[float, int]] = []
        for idx, s in enumerate(self.submaps):
            travel = cur.travel_m - self.kfs[s.last].travel_m
            if travel < self.p.loop_min_travel_m:
                continue
            radius = min(self.p.loop_max_radius_m,
                         self.p.loop_radius_m + self.p.loop_radius_per_m * travel)
            d = np.hypot(poses[s.first:s.last + 1, 0] - cur.pose.x,
                         poses[s.first:s.last + 1, 1] - cur.pose.y)
            dmin = float(d.min())
            if dmin <= radius:
                out.append((dmin, idx))
        out.sort()
        return [idx for _, idx in out[:self.p.loop_candidates]]

    def _match(self, idx: int, k: int, query: F64) -> Hypothesis | None:
        s = self.submaps[idx]
        cur = self.kfs[k]
        travel = cur.travel_m - self.kfs[s.anchor].travel_m
        radius = min(self.p.loop_max_radius_m,
                     self.p.loop_radius_m + self.p.loop_radius_per_m * travel)
        grid = self._grid(idx)
        assert s.pmap is not None
        guess = self.kfs[s.anchor].pose.inverse() @ cur.pose
        self.tried += 1
        sub = query[voxel_subsample(query, 0.1)]
        found = grid.search(sub, guess, radius, self.p.loop_search_rad, self.p.loop_step_rad,
                            self.p.loop_min_score)
        if found is None:
            return None
        # The runner-up outside the best peak: a match that is as good elsewhere is ambiguous
        # (a corridor, a row of identical doors).
        second = grid.search(sub, guess, radius, self.p.loop_search_rad, self.p.loop_step_rad,
                             self.p.loop_ambiguity * found[1],
                             exclude=(found[0], self.p.loop_peak_m, self.p.loop_peak_rad))
        axis: F64 | None = None
        if second is not None:
            if abs(wrap_angle(second[0].yaw - found[0].yaw)) > self.p.loop_peak_rad:
                self.ambiguous += 1
                return None
            axis = np.array([second[0].x - found[0].x, second[0].y - found[0].y])
        ref = refine(s.pmap, query, found[0], sigma_m=self.p.match_sigma_m)
        if ref.inlier_fraction < self.p.loop_min_inliers:
            return None
        info = to_local_info(ref.info, ref.pose.yaw)
        if axis is not None:
            # Keep only what the match fixes: nothing along the line joining the two peaks.
            c, sn = math.cos(ref.pose.yaw), math.sin(ref.pose.yaw)
            d = np.array([c * axis[0] + sn * axis[1], -sn * axis[0] + c * axis[1]])
            d /= max(float(np.linalg.norm(d)), 1e-9)
            proj = np.eye(3)
            proj[:2, :2] -= np.outer(d, d)
            info = proj @ info @ proj
            self.ambiguous += 1
        self.matched += 1
        return Hypothesis(s.anchor, k, ref.pose, info, found[1], ref.inlier_fraction)

    # --- verification --------------------------------------------------------------------------
    def _chi2_pair(self, a: Hypothesis, b: Hypothesis) -> float:
        """Consistency of two hypotheses: the cycle anchor_a → kf_a → kf_b → anchor_b → anchor_a
        (trajectory legs from the current estimate) should be the identity."""
        xa, xb = self.kfs[a.anchor].pose, self.kfs[b.anchor].pose
        ka, kb = self.kfs[a.kf].pose, self.kfs[b.kf].pose
        leg = ka.inverse() @ kb
        pred = a.z @ leg @ b.z.inverse()  # anchor_b in anchor_a's frame, through the loops
        e = _err(xa.inverse() @ xb, pred)  # in anchor_b's frame
        legs = (abs(self.kfs[a.kf].travel_m - self.kfs[b.kf].travel_m)
                + abs(self.kfs[a.anchor].travel_m - self.kfs[b.anchor].travel_m))
        tol_m = self.p.loop_tol_m + self.p.loop_tol_per_m * legs
        tol_r = self.p.loop_tol_rad + 0.1 * self.p.loop_tol_per_m * legs
        # First-order propagation of both matches' covariances into the error's frame.
        ja = adjoint((leg @ b.z.inverse()).inverse())
        jb = adjoint(b.z)
        cov = (ja @ _cov(a.info) @ ja.T + jb @ _cov(b.info) @ jb.T
               + np.diag([tol_m**2, tol_m**2, tol_r**2]))
        return float(e @ np.linalg.solve(cov, e))

    def _chi2_estimate(self, h: Hypothesis) -> float:
        """Agreement of a hypothesis with the current estimate of the graph."""
        est = self.kfs[h.anchor].pose.inverse() @ self.kfs[h.kf].pose
        e = _err(est, h.z)
        cov = _cov(h.info) + np.diag([self.p.loop_tol_m**2 * 4, self.p.loop_tol_m**2 * 4,
                                      (2 * self.p.loop_tol_rad) ** 2])
        return float(e @ np.linalg.solve(cov, e))

    def _verify(self, hyp: Hypothesis) -> list[int]:
        travel = self.kfs[hyp.kf].travel_m
        anchor_travel = self.kfs[hyp.anchor].travel_m
        span = self.p.loop_pending_m + 2.0 * self.p.submap_m
        kf_t, anchor_t = self._connected
        if (travel - kf_t <= self.p.loop_connected_m and abs(anchor_travel - anchor_t) <= span
                and self._chi2_estimate(hyp) <= self.p.loop_gate_chi2):
            return self._accept([hyp])
        self.pending = [h for h in self.pending
                        if travel - self.kfs[h.kf].travel_m <= self.p.loop_pending_m]
        agree = [h for h in self.pending
                 if abs(self.kfs[h.anchor].travel_m - anchor_travel) <= span
                 and h.kf != hyp.kf and self._chi2_pair(hyp, h) <= self.p.loop_gate_chi2]
        self.pending.append(hyp)
        if len(agree) + 1 < self.p.loop_consistent:
            if self.pending and len(self.pending) > 1 and not agree:
                self.rejected_inconsistent += 1
            return []
        group = [*agree, hyp]
        self.pending = [h for h in self.pending if h not in group]
        self.new_region = True
        return self._accept(group)

    def _accept(self, group: list[Hypothesis]) -> list[int]:
        added = []
        for h in group:
            e = self.graph.add_edge(h.anchor, h.kf, h.z, h.info, robust=True)
            self.accepted.append((e, h))
            added.append(e)
            log.debug("loop closure: keyframe %d -> %d (score %.2f, inliers %.2f)", h.anchor,
                      h.kf, h.score, h.inliers)
        last = max(group, key=lambda h: self.kfs[h.kf].travel_m)
        self._connected = (self.kfs[last.kf].travel_m, self.kfs[last.anchor].travel_m)
        return added

    def correction(self, hyp: Hypothesis) -> float:
        """How far (metres) a hypothesis moves its keyframe from the current estimate."""
        est = self.kfs[hyp.anchor].pose.inverse() @ self.kfs[hyp.kf].pose
        return est.distance_to(hyp.z) + abs(wrap_angle(est.yaw - hyp.z.yaw))
