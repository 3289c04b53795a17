"""Is the way clear again? Judged from fresh lidar evidence along the route, not the costmap.

While the rover holds for help, "the way is clear" used to be a plan on the live costmap
(:class:`curio.bt.probe.WayProbe`). The recovery's costmap clearing made the way look clear
for a moment while a door was still closed ("Thanks!" twice), and cells the lidar could not
re-observe kept it asking long after the door had opened. :class:`ClearanceProbe` (same
interface: ``start``, ``poll``, ``busy``, ``reset``) decides from the scans themselves:

1. **The route**: once per help episode, a plan from the rover to the held waypoint on the
   *static* map (walls, keep-out zones, inflated as in the costmap; no obstacle layer), off the
   loop (``Clock.offload``): the way the rover wants to take, through the doorway.
2. **Every new scan** after the request is judged along that route (:func:`judge_route`):
   route samples every ``STEP_M`` from ``SKIP_M`` ahead of the rover up to ``RANGE_M``, as long
   as the laser has a line of sight to them over the static map (a corner ends the judged
   stretch). A sample is *seen free* when a beam at its bearing reaches past it; the route is
   *blocked* where the beams end short of it on something the static map does not explain, or
   where such a return lies within ``corridor_half_m`` of the judged stretch (the rover's half
   width).
3. **Clear** = nothing blocks and the stretch seen free reaches past the place the blockage was
   first seen (plus ``PAST_M``), or at least ``MIN_EVIDENCE_M`` when it was never seen. Each
   answer carries the scan's stamp, so the help request only counts evidence newer than the
   request; a cleared costmap changes nothing here.

A door that opens is seen by the next scan (0.1 s); the tree then wants the way clear for
``bt.help_clear_s``. The blocking points go on ``/help_blockage`` (``Obstacles`` in ``map``) so
the dashboard shows what blocks the rover.
"""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, Obstacles
from curio.core.topics import HELP_BLOCKAGE, POSE, SCAN
from curio.nav.api import NavError
from curio.nav.costs import INSCRIBED, NO_INFORMATION, inflation_costs

__all__ = ["ClearanceProbe", "RouteJudgement", "StaticView", "judge_route"]

log = logging.getLogger("curio.nav.clearance")

F64 = npt.NDArray[np.float64]

STEP_M = 0.1
SKIP_M = 0.45
RANGE_M = 4.0
MIN_EVIDENCE_M = 1.5
PAST_M = 0.5
EXPLAINED_M = 0.12   # a return this close to a mapped wall is the wall
TOLERANCE_M = 0.12   # a beam reaching this close to a sample counts as reaching it


@dataclass(frozen=True)
class ProbeAnswer:
    """One judgement: ``started_s`` is the scan's stamp (what the help request compares with
    its own time), ``clear`` whether the way is clear, ``reason`` why not."""

    started_s: float
    clear: bool
    reason: str = ""


@dataclass(frozen=True)
class RouteJudgement:
    """What one scan says about the route.

    Attributes:
        seen_free_m: along the route from the rover, how far it is seen free without a gap.
        blocked_at_m: where along the route it is first blocked (None: nowhere seen).
        blockers: unexplained returns in the way, ``(N, 2)`` in ``map``.
        judged_m: how far along the route the scan could judge (line of sight, range).
    """

    seen_free_m: float
    blocked_at_m: float | None
    blockers: F64
    judged_m: float


class StaticView:
    """The static map as the judge needs it: occupied cells and the distance to them.

    Args:
        occupied: ``(H, W)`` bool, row 0 at the bottom.
        resolution_m, origin: where the grid lies in ``map``.
    """

    def __init__(self, occupied: npt.NDArray[np.bool_], resolution_m: float,
                 origin: Pose2D) -> None:
        self.occupied = occupied
        self.resolution_m = resolution_m
        self.origin = origin
        self._inv = origin.inverse()
        self.dist_m = np.asarray(ndimage.distance_transform_edt(~occupied)) * resolution_m

    def _cells(self, xy: F64) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64],
                                       npt.NDArray[np.bool_]]:
        g = self._inv.transform_points(xy) / self.resolution_m
        cols = np.floor(g[:, 0]).astype(np.int64)
        rows = np.floor(g[:, 1]).astype(np.int64)
        h, w = self.occupied.shape
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        return rows, cols, inside

    def distance(self, xy: F64) -> F64:
        """Distance of each map point to the nearest occupied cell, metres (0 off the map)."""
        rows, cols, inside = self._cells(xy)
        out = np.zeros(len(xy))
        out[inside] = self.dist_m[rows[inside], cols[inside]]
        return out

    def line_of_sight(self, origin_xy: tuple[float, float], targets: F64) -> npt.NDArray[
            np.bool_]:
        """Whether the segment from ``origin_xy`` to each target crosses no occupied cell."""
        if len(targets) == 0:
            return np.zeros(0, dtype=bool)
        o = np.asarray(origin_xy, dtype=np.float64)
        length = float(np.hypot(*(targets - o).T).max())
        n = max(2, math.ceil(length / (0.5 * self.resolution_m)))
        t = np.linspace(0.0, 1.0, n)[None, :, None]
        pts = o[None, None, :] + t * (targets[:, None, :] - o[None, None, :])
        rows, cols, inside = self._cells(pts.reshape(-1, 2))
        hit = np.ones(len(rows), dtype=bool)  # off the map counts as blocked
        hit[inside] = self.occupied[rows[inside], cols[inside]]
        return np.asarray(~hit.reshape(len(targets), n)[:, :-1].any(axis=1))


def _samples(route: F64, rover: Pose2D) -> tuple[F64, F64]:
    """Route samples every ``STEP_M`` from the point nearest the rover, with their distance
    along the route from the rover."""
    d = np.hypot(route[:, 0] - rover.x, route[:, 1] - rover.y)
    route = route[int(np.argmin(d)):]
    seg = np.hypot(*np.diff(route, axis=0).T) if len(route) > 1 else np.zeros(0)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= 0.0:
        return np.zeros((0, 2)), np.zeros(0)
    s = np.arange(SKIP_M, min(cum[-1], RANGE_M) + 1e-9, STEP_M)
    xy = np.stack([np.interp(s, cum, route[:, 0]), np.interp(s, cum, route[:, 1])], axis=1)
    return xy, s


def judge_route(route: F64, rover: Pose2D, laser: Pose2D, scan: LaserScan, static: StaticView,
                corridor_half_m: float) -> RouteJudgement:
    """Judge the route (``(K, 2)`` in ``map``) against one scan taken at ``laser`` (the laser's
    pose in ``map``) with the rover at ``rover`` (see the module docstring)."""
    xy, s = _samples(route, rover)
    empty = np.zeros((0, 2))
    if len(s) == 0:
        return RouteJudgement(0.0, None, empty, 0.0)
    sight = static.line_of_sight((laser.x, laser.y), xy)
    stop = int(np.argmin(sight)) if not sight.all() else len(s)
    xy, s = xy[:stop], s[:stop]
    if len(s) == 0:
        return RouteJudgement(0.0, None, empty, 0.0)
    # Beams at each sample's bearing (and the neighbours: dropouts, the corridor's width).
    rel = laser.inverse().transform_points(xy)
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    n = len(scan.ranges_m)
    idx = np.round((bearing - scan.angle_min_rad) / scan.angle_increment_rad).astype(np.int64)
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    reach = np.full(len(s), -np.inf)
    for k in (-1, 0, 1):
        r = ranges[(idx + k) % n]
        r = np.where(np.isnan(r), -np.inf, r)  # invalid returns say nothing
        reach = np.maximum(reach, r)
    free = reach >= dist - TOLERANCE_M
    short: float | None = None  # where a beam first ends short of the route on something new
    if not free.all():
        k = int(np.argmin(free))
        end = laser.transform_points(np.array([[max(reach[k], 0.0) * math.cos(bearing[k]),
                                                max(reach[k], 0.0) * math.sin(bearing[k])]]))
        if static.distance(end)[0] <= EXPLAINED_M:  # a mapped wall hides the rest: stop there
            xy, s, free = xy[:k], s[:k], free[:k]
        else:
            short = float(s[k])
    if len(s) == 0:
        return RouteJudgement(0.0, None, empty, 0.0)
    seen_free = float(s[int(np.argmin(free))] - STEP_M) if not free.all() else float(s[-1])
    # Unexplained returns in the corridor along the judged stretch.
    pts_laser = scan.points(None, range_max_m=min(scan.range_max_m, RANGE_M + 1.0))
    pts = laser.transform_points(pts_laser) if len(pts_laser) else empty
    blockers = empty
    blocked_at: float | None = None
    if len(pts):
        pts = pts[static.distance(pts) > EXPLAINED_M]
    if len(pts):
        dd = np.hypot(pts[:, None, 0] - xy[None, :, 0], pts[:, None, 1] - xy[None, :, 1])
        near = dd.min(axis=1) <= corridor_half_m
        blockers = pts[near]
        if near.any():
            blocked_at = float(s[int(np.argmin(dd[near].min(axis=0)))])
    if short is not None:
        blocked_at = short if blocked_at is None else min(blocked_at, short)
    return RouteJudgement(seen_free, blocked_at, blockers, float(s[-1]))


class ClearanceProbe:
    """Fresh-evidence judge of the held route (see the module docstring); the
    :class:`~curio.bt.probe.WayProbe` interface.

    Args:
        planner: ``plan(start, goal, costs, resolution_m, origin)``.
        costmap: the costmap (its static map, keep-out layer, inflation and geometry).
        bus, clock: injected.
        laser_in_base: the laser's mount.
        corridor_half_m: returns this close to the route block it (the rover's half width).
    """

    def __init__(self, planner: Any, costmap: Any, bus: Bus, clock: Clock,
                 laser_in_base: Pose2D, corridor_half_m: float) -> None:
        self.planner = planner
        self.costmap = costmap
        self.bus = bus
        self.clock = clock
        self.laser_in_base = laser_in_base
        self.corridor_half_m = corridor_half_m
        self.route: F64 | None = None
        self.static: StaticView | None = None
        self.blocked_at_m: float | None = None
        self.last: ProbeAnswer | None = None
        self.count = 0
        self._job: asyncio.Future[list[Pose2D]] | None = None
        self._scan_stamp = -math.inf
        self._goal: Pose2D | None = None
        # (static map, keep-out mask, costs) of the last static_costs()
        self._static_costs: tuple[Any, npt.NDArray[np.bool_], npt.NDArray[np.uint8]] | None \
            = None

    @property
    def busy(self) -> bool:
        """The route is being planned."""
        return self._job is not None and not self._job.done()

    def reset(self) -> None:
        """A new help episode: plan the route again, forget the evidence."""
        if self._job is not None and not self._job.done():
            self._job.cancel()
        self._job = None
        self.route = None
        self.blocked_at_m = None
        self.last = None
        self._goal = None
        self._scan_stamp = -math.inf

    def static_costs(self) -> npt.NDArray[np.uint8]:
        """The static map and keep-out zones, inflated as in the costmap (no obstacles);
        read-only, and made again only when the static map or the zones changed (two
        whole-map distance transforms: a help episode with no route asked for them every
        quarter second, tens of MB of temporaries each time)."""
        cm = self.costmap
        keepout = cm.keepout_mask() if hasattr(cm, "keepout_mask") \
            else np.zeros(cm.static_map.data.shape, dtype=bool)
        cached = self._static_costs
        if cached is not None and cached[0] is cm.static_map \
                and np.array_equal(cached[1], keepout):
            return cached[2]
        occupied = cm.static_map.occupied_mask()
        lethal = occupied | keepout
        dist = np.asarray(ndimage.distance_transform_edt(~lethal)) * cm.resolution_m
        costs = inflation_costs(dist, cm.inscribed_radius_m, cm.cfg.inflation_radius_m,
                                cm.cfg.cost_scaling_factor)
        unknown = cm.static_map.unknown_mask() & (costs < INSCRIBED)
        costs[unknown] = NO_INFORMATION
        costs.setflags(write=False)  # shared by every plan of the probe, as the costmap's
        self.static = StaticView(occupied, cm.resolution_m, cm.origin)
        self._static_costs = (cm.static_map, keepout, costs)
        return costs

    def start(self, goal: Pose2D, now_s: float) -> bool:
        """Plan the route to ``goal`` (once per episode); False without a pose."""
        if self.route is not None or self.busy:
            return True
        pose_msg = self.bus.latest(POSE)
        if pose_msg is None:
            return False
        self._goal = goal
        self.count += 1
        costs = self.static_costs()
        self._job = self.clock.offload(self.planner.plan, pose_msg.pose, goal, costs,
                                       self.costmap.resolution_m, self.costmap.origin)
        self.poll()
        return True

    def poll(self) -> ProbeAnswer | None:
        """Collect the route; judge a scan newer than the last one judged."""
        job = self._job
        if job is not None and job.done():
            self._job = None
            try:
                poses = job.result()
                self.route = np.array([[p.x, p.y] for p in poses], dtype=np.float64)
            except NavError as exc:  # no way even on the static map: nothing to judge
                self.last = ProbeAnswer(self.clock.now(), False, f"no route: {exc}")
            except Exception as exc:  # a planner bug must not stop the tree
                log.warning("clearance probe: planning failed: %s", exc)
        if self.route is None or self.static is None:
            return self.last
        scan = self.bus.latest(SCAN)
        pose_msg = self.bus.latest(POSE)
        if scan is None or pose_msg is None or scan.stamp <= self._scan_stamp:
            return self.last
        self._scan_stamp = scan.stamp
        self.last = self._judge(scan, pose_msg.pose)
        return self.last

    def _judge(self, scan: LaserScan, rover: Pose2D) -> ProbeAnswer:
        assert self.route is not None and self.static is not None
        j = judge_route(self.route, rover, rover @ self.laser_in_base, scan, self.static,
                        self.corridor_half_m)
        self.bus.publish(HELP_BLOCKAGE, Obstacles(scan.stamp, circles=tuple(
            (float(x), float(y), 0.05) for x, y in j.blockers[:: max(1, len(j.blockers) // 40)])))
        if j.blocked_at_m is not None:
            if self.blocked_at_m is None or j.blocked_at_m < self.blocked_at_m:
                self.blocked_at_m = j.blocked_at_m
            return ProbeAnswer(scan.stamp, False, f"blocked {j.blocked_at_m:.1f} m ahead")
        total = float(np.hypot(*np.diff(self.route, axis=0).T).sum()) if len(
            self.route) > 1 else 0.0
        if self.blocked_at_m is None:  # never seen blocked: want enough of the route seen
            need = min(MIN_EVIDENCE_M, max(0.0, total - SKIP_M - STEP_M))
        else:  # seen past where it was blocked (as far as the line of sight goes)
            past = self.blocked_at_m
            if j.judged_m + 1e-9 < past:
                return ProbeAnswer(scan.stamp, False, "cannot see past where it was blocked")
            need = min(self.blocked_at_m + PAST_M, j.judged_m)
        if j.seen_free_m + 1e-9 >= need:
            return ProbeAnswer(scan.stamp, True)
        return ProbeAnswer(scan.stamp, False, f"seen free for {j.seen_free_m:.1f} m of "
                                             f"{need:.1f} m")
