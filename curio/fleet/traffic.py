"""Traffic between rovers: the others as moving obstacles with known intent, and one rover at
a time through narrow passages.

Every rover publishes, a few times a second, its pose, velocity, the stretch of its plan
ahead and its right-of-way state (``curio/<rover>/traffic``); every rover reads the others'
(:class:`PeerTable`). The lidar and the costmap already see the other rovers as obstacles;
this module adds what a lidar cannot know — where they are going:

* :class:`PassageFinder` finds the *narrow passages* on a plan: stretches where the free width
  across the plan (wall to wall on the static map, measured perpendicular to the plan) is under
  ``fleet.traffic.narrow_width_m`` — the doorways of the default building (0.9–1.2 m) are, its
  2.35 m corridor is not.
* :class:`RightOfWay` decides, for the first passage ahead that another rover's plan or pose
  also uses in the other direction (following in the same direction is left to the lidar):
  a rover already *in* the passage has it; else a rover that has claimed it (state ``go``)
  keeps it; else the one that will be there sooner by more than ``tie_margin_s`` (distance
  along its plan at a nominal speed plus the time its turns take, :func:`eta_s`); else the
  one whose name sorts first. The other gives way (state ``yield``): it keeps driving until it
  is ``stop_before_m``..``wait_back_m`` before the passage, at the spot clearest of the other's
  way (the *staging point*), holds there, and goes as soon as the other has left the passage
  (``clear_after_m``) or stopped using it. On its way to the staging point it slows
  (:meth:`TrafficNode.speed_limit`, a limit the controller applies) so that it arrives shortly
  before the other is expected through, rather than parking in front of the passage for the
  other's whole approach. Decisions are latched: a rover that goes keeps the
  passage until it is through; one that yields to a rover that yields too (a race) goes if its
  name sorts first.
* :class:`TrafficNode` is the rover's part: it runs the rule at ``rate_hz`` and gives the
  navigator its hold (:meth:`TrafficNode.hold`, one of ``NavigatorNode.holds``): while it holds
  the goal stays active, the progress checkers pause and the blocked-path detector does not
  count the wait. Events: ``traffic.yield`` (to whom, where), ``traffic.waiting`` (stopped at
  the staging point), ``traffic.resume`` (how long it waited), ``traffic.go``.

A peer not heard from for ``peer_timeout_s`` is ignored here (its link may be down): the lidar,
the costmap and the safety stage still keep the rovers apart, and the rule resumes when it is
heard again.

**For the people-aware controller** (``people`` branch): :meth:`PeerTable.tracks` gives the
other rovers as :class:`MovingObstacle` — an id, position, velocity, radius and the path they
intend to drive — the shape a people tracker's tracks have, so a predictor can take rovers as
tracks with known intent instead of extrapolating them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import FleetTrafficConfig
from curio.core.geometry import Pose2D
from curio.core.messages import Event
from curio.core.topics import EVENTS, ODOM, PLAN, POSE
from curio.estimation.maps import OccupancyGrid

__all__ = [
    "Decision",
    "MovingObstacle",
    "Passage",
    "PassageFinder",
    "PeerTable",
    "PeerTrack",
    "RightOfWay",
    "TrafficNode",
    "clear_eta_s",
    "eta_s",
]

log = logging.getLogger("curio.fleet.traffic")

F64 = npt.NDArray[np.float64]
SAMPLE_M = 0.1          # plans are resampled at this spacing to look for passages
MERGE_GAP_M = 0.4       # narrow stretches closer than this are one passage
INSIDE_M = 0.45         # a rover this near a passage's centre line is in it
SAME_ZONE_M = 1.0       # two rovers' passages with centres this close are the same one
FOLLOW_DOT = 0.3        # travel directions with a cosine above this follow each other
WAIT_SPEED_MPS = 0.03   # slower than this while holding: waiting at the staging point
NOMINAL_SPEED_MPS = 0.25  # for arrival estimates (the controller drives at up to 0.3 m/s)
TURN_S_PER_RAD = 2.0    # and each radian of turning on the way costs this long
ETA_STEP_M = 0.5        # the plan's resolution for those estimates
SLOW_APPROACH_MIN_MPS = 0.08  # a rover giving way never creeps slower than this to its staging


# --- geometry ---------------------------------------------------------------------------------

def _resample(points: F64, step_m: float) -> tuple[F64, F64]:
    """Points every ``step_m`` along a polyline and their arc lengths."""
    if len(points) < 2:
        return points.copy(), np.zeros(len(points))
    seg = np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0.0:
        return points[:1].copy(), np.zeros(1)
    grid = np.arange(0.0, s[-1], step_m)
    grid = np.append(grid, s[-1]) if grid[-1] < s[-1] else grid
    out = np.stack([np.interp(grid, s, points[:, 0]), np.interp(grid, s, points[:, 1])], axis=1)
    return out, grid


def _dist_to_polyline(p: F64, line: F64) -> F64:
    """Distance from each point of ``p`` (K, 2) to the polyline ``line`` (M, 2)."""
    p = np.atleast_2d(p)
    if len(line) == 1:
        return np.asarray(np.hypot(p[:, 0] - line[0, 0], p[:, 1] - line[0, 1]))
    a, b = line[:-1], line[1:]
    ab = b - a
    ab2 = np.maximum((ab ** 2).sum(axis=1), 1e-12)
    ap = p[:, None, :] - a[None, :, :]
    t = np.clip((ap * ab[None]).sum(axis=2) / ab2[None], 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    d = np.hypot(p[:, None, 0] - closest[..., 0], p[:, None, 1] - closest[..., 1])
    return np.asarray(d.min(axis=1))


@dataclass(frozen=True)
class Passage:
    """A narrow stretch of a plan.

    Attributes:
        s_in_m, s_out_m: where it starts and ends along the plan (arc length from the plan's
            point nearest the rover), metres.
        line: its centre line, ``(K, 2)`` map metres.
        width_m: its narrowest free width.
        heading_rad: the direction the plan crosses it in.
    """

    s_in_m: float
    s_out_m: float
    line: F64
    width_m: float
    heading_rad: float

    @property
    def centre(self) -> tuple[float, float]:
        """The middle of its centre line."""
        mid = self.line[len(self.line) // 2]
        return float(mid[0]), float(mid[1])

    def distance(self, points: F64) -> F64:
        """Distance from each of ``points`` to the passage's centre line."""
        return _dist_to_polyline(points, self.line)


class PassageFinder:
    """Finds narrow passages along plans on a static map (see the module docstring).

    Args:
        grid: returns the static map (re-read when it changes).
        narrow_width_m: narrower than this is a passage.
    """

    def __init__(self, grid: Callable[[], OccupancyGrid], narrow_width_m: float) -> None:
        self.grid = grid
        self.narrow_width_m = narrow_width_m
        self._grid_id = -1
        self._blocked: npt.NDArray[np.bool_] = np.zeros((1, 1), dtype=bool)
        self._g: OccupancyGrid | None = None

    def _map(self) -> OccupancyGrid:
        g = self.grid()
        if id(g) != self._grid_id:
            self._grid_id = id(g)
            self._g = g
            self._blocked = g.occupied_mask() | g.unknown_mask()
        assert self._g is not None
        return self._g

    def widths(self, points: F64) -> F64:
        """The free width across the polyline at each of its points, metres (capped at
        ``narrow_width_m``)."""
        g = self._map()
        n = len(points)
        if n < 2:
            return np.full(n, self.narrow_width_m)
        tangent = np.gradient(points, axis=0)
        norm = np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-9)
        normal = np.stack([-tangent[:, 1] / norm, tangent[:, 0] / norm], axis=1)
        res = g.resolution_m
        steps = np.arange(1, math.ceil(self.narrow_width_m / res) + 1) * res
        total = np.zeros(n)
        for side in (1.0, -1.0):
            pts = points[:, None, :] + side * steps[None, :, None] * normal[:, None, :]
            cells = g.world_to_cells(pts.reshape(-1, 2))
            rows, cols = cells[:, 0], cells[:, 1]
            inside = (rows >= 0) & (rows < g.height) & (cols >= 0) & (cols < g.width)
            flat = np.ones(len(rows), dtype=bool)
            flat[inside] = self._blocked[rows[inside], cols[inside]]
            hit = flat.reshape(n, len(steps))
            first = np.where(hit.any(axis=1), steps[np.argmax(hit, axis=1)], self.narrow_width_m)
            total += first
        return np.minimum(total, self.narrow_width_m)

    def find(self, plan_xy: F64, start_s_m: float, ahead_m: float) -> list[Passage]:
        """The passages on ``plan_xy`` between arc length ``start_s_m`` and ``ahead_m``
        beyond it, in order; their ``s`` measured from ``start_s_m``."""
        pts, s = _resample(plan_xy, SAMPLE_M)
        keep = (s >= start_s_m - 1e-9) & (s <= start_s_m + ahead_m)
        pts, s = pts[keep], s[keep] - start_s_m
        if len(pts) < 3:
            return []
        widths = self.widths(pts)
        narrow = widths < self.narrow_width_m - 1e-6
        runs: list[list[int]] = []
        for i in np.flatnonzero(narrow):
            if runs and s[i] - s[runs[-1][1]] <= MERGE_GAP_M:
                runs[-1][1] = int(i)
            else:
                runs.append([int(i), int(i)])
        out: list[Passage] = []
        for first, last in runs:
            lo, hi = max(0, first - 1), min(len(pts) - 1, last + 1)
            line = pts[lo:hi + 1]
            d = pts[hi] - pts[lo]
            out.append(Passage(float(s[lo]), float(s[hi]), line,
                               float(widths[first:last + 1].min()),
                               math.atan2(float(d[1]), float(d[0]))))
        return out


# --- peers ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MovingObstacle:
    """Another rover as a tracked moving obstacle with known intent (for predictors).

    Attributes:
        id: ``rover:<name>``.
        x_m, y_m: position in ``map``; vx_mps, vy_mps: velocity in ``map``.
        radius_m: a circle that holds its footprint.
        path: the points (``map``) it intends to drive next.
        stamp_wall_s: when it was measured (the sender's wall clock).
    """

    id: str
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    radius_m: float
    path: tuple[tuple[float, float], ...]
    stamp_wall_s: float


@dataclass
class PeerTrack:
    """The latest traffic message of another rover."""

    name: str
    wall_s: float
    pose: Pose2D
    speed_mps: float = 0.0
    goal: bool = False
    plan: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    state: str = "clear"
    zone: tuple[float, float] | None = None
    yield_to: str | None = None
    inside: bool = False
    radius_m: float = 0.45
    stop_in_m: float | None = None  # yielding: it holds after driving this far along its plan

    @classmethod
    def from_message(cls, name: str, msg: dict[str, Any]) -> PeerTrack:
        """Parse a traffic message (raises ValueError/KeyError/TypeError when malformed)."""
        plan = np.asarray(msg.get("plan") or [], dtype=np.float64).reshape(-1, 2)
        zone = msg.get("zone")
        return cls(name, float(msg["t"]), Pose2D(float(msg["x"]), float(msg["y"]),
                                                 float(msg["yaw"])),
                   float(msg.get("v", 0.0)), bool(msg.get("goal", False)), plan,
                   str(msg.get("state", "clear")),
                   (float(zone[0]), float(zone[1])) if zone else None,
                   msg.get("yield") or None, bool(msg.get("inside", False)),
                   float(msg.get("r", 0.45)),
                   float(msg["stop_in"]) if msg.get("stop_in") is not None else None)

    def points(self) -> F64:
        """Its pose followed by its plan ahead, ``(K, 2)``."""
        return np.vstack([[self.pose.x, self.pose.y], self.plan]) if len(self.plan) else \
            np.array([[self.pose.x, self.pose.y]])

    def claims(self, zone: Passage) -> bool:
        """Whether it has claimed (state ``go``) this passage."""
        return self.state == "go" and self.zone is not None and math.hypot(
            self.zone[0] - zone.centre[0], self.zone[1] - zone.centre[1]) < SAME_ZONE_M

    def yields_to(self, me: str, zone: Passage) -> bool:
        """Whether it gives way to ``me`` at this passage."""
        return self.state == "yield" and self.yield_to == me and self.zone is not None and \
            math.hypot(self.zone[0] - zone.centre[0], self.zone[1] - zone.centre[1]) \
            < SAME_ZONE_M


class PeerTable:
    """The other rovers' latest traffic messages, by name."""

    def __init__(self, me: str) -> None:
        self.me = me
        self.peers: dict[str, PeerTrack] = {}
        self.malformed = 0

    def update(self, name: str, msg: dict[str, Any]) -> None:
        """Take a traffic message from ``name`` (its own and malformed ones are dropped)."""
        if name == self.me:
            return
        try:
            track = PeerTrack.from_message(name, msg)
        except (KeyError, ValueError, TypeError):
            self.malformed += 1
            return
        old = self.peers.get(name)
        if old is None or track.wall_s >= old.wall_s:
            self.peers[name] = track

    def fresh(self, now_wall_s: float, timeout_s: float) -> list[PeerTrack]:
        """Peers heard from within ``timeout_s``, by name."""
        return [p for _, p in sorted(self.peers.items())
                if now_wall_s - p.wall_s <= timeout_s]

    def tracks(self, now_wall_s: float, timeout_s: float) -> list[MovingObstacle]:
        """The fresh peers as :class:`MovingObstacle` tracks (see the module docstring)."""
        out = []
        for p in self.fresh(now_wall_s, timeout_s):
            c, s = math.cos(p.pose.yaw), math.sin(p.pose.yaw)
            out.append(MovingObstacle(f"rover:{p.name}", p.pose.x, p.pose.y,
                                      p.speed_mps * c, p.speed_mps * s, p.radius_m,
                                      tuple((float(x), float(y)) for x, y in p.plan),
                                      p.wall_s))
        return out


# --- the rule ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class Decision:
    """The right-of-way state after one step.

    Attributes:
        state: ``clear`` (no shared passage ahead), ``go`` (this rover has the passage) or
            ``yield`` (it gives way).
        zone: the passage concerned (None when clear).
        yield_to: the rover it gives way to.
        hold_s_m: with ``yield``: hold once the rover is this far (along its plan) or less
            before the passage's start.
        inside: the rover is in the passage.
    """

    state: str = "clear"
    zone: Passage | None = None
    yield_to: str | None = None
    hold_s_m: float = 0.0
    inside: bool = False


@dataclass
class MyView:
    """What the rule knows about this rover at one step."""

    name: str
    pose: Pose2D
    plan: F64
    start_s_m: float
    goal: bool


class RightOfWay:
    """The right-of-way rule with its latched state (see the module docstring)."""

    def __init__(self, cfg: FleetTrafficConfig, finder: PassageFinder,
                 robot_width_m: float) -> None:
        self.cfg = cfg
        self.finder = finder
        self.robot_width_m = robot_width_m
        self.decision = Decision()
        self._claim: tuple[float, float] | None = None

    def step(self, me: MyView, peers: list[PeerTrack]) -> Decision:
        """Decide for this step (peers: the fresh ones)."""
        if not me.goal or len(me.plan) < 2:
            self._claim = None
            self.decision = Decision()
            return self.decision
        zones = self.finder.find(me.plan, me.start_s_m, self.cfg.lookahead_m)
        here = np.array([[me.pose.x, me.pose.y]])
        for zone in zones:
            inside = bool(zone.distance(here)[0] <= INSIDE_M and zone.s_in_m <= INSIDE_M)
            rivals = [p for p in peers if p.goal and self._uses(p, zone)]
            if not rivals:
                continue
            winner = self._resolve(me, zone, inside, rivals)
            if winner is None:
                self._claim = zone.centre
                self.decision = Decision("go", zone, None, 0.0, inside)
            else:
                self._claim = None
                self.decision = Decision("yield", zone, winner.name,
                                         self._hold_distance(me, zone, winner), inside)
            return self.decision
        if self._claim is not None and zones and _same(zones[0].centre, self._claim):
            self.decision = Decision("go", zones[0], None, 0.0,
                                     bool(zones[0].distance(here)[0] <= INSIDE_M))
            return self.decision
        self._claim = None
        self.decision = Decision()
        return self.decision

    def _uses(self, peer: PeerTrack, zone: Passage) -> bool:
        """Whether ``peer`` is in or heads through ``zone`` other than following us."""
        pose_d = float(zone.distance(np.array([[peer.pose.x, peer.pose.y]]))[0])
        near_pose = pose_d <= max(self.cfg.clearance_m, self.cfg.clear_after_m)
        plan = _resample(peer.plan, SAMPLE_M)[0] if len(peer.plan) >= 2 else peer.plan
        plan_d = zone.distance(plan) if len(plan) else np.zeros(0)
        near_plan = bool(len(plan_d)) and float(plan_d.min()) <= self.cfg.clearance_m
        if not (near_pose or near_plan):
            return False
        heading = _peer_heading(peer, plan, plan_d)
        if heading is None:
            return near_pose
        cos = math.cos(heading - zone.heading_rad)
        return cos <= FOLLOW_DOT

    def _resolve(self, me: MyView, zone: Passage, inside: bool,
                 rivals: list[PeerTrack]) -> PeerTrack | None:
        """The rival this rover must give way to, or None (it goes)."""
        mine = self._claim is not None and _same(self._claim, zone.centre)
        for p in rivals:
            p_inside = (p.inside and p.zone is not None and _same(p.zone, zone.centre)) or \
                float(zone.distance(np.array([[p.pose.x, p.pose.y]]))[0]) <= INSIDE_M
            if inside and not p_inside:
                continue
            if p_inside and not inside:
                return p
            if p.yields_to(me.name, zone):
                continue
            if mine and not p.claims(zone):
                continue
            if p.claims(zone) and not mine:
                return p
            t_me = eta_s(self._ahead(me), me.pose.yaw, zone)
            t_p = eta_s(p.points(), p.pose.yaw, zone)
            if t_p + self.cfg.tie_margin_s < t_me and not mine:
                return p
            if t_me + self.cfg.tie_margin_s < t_p:
                continue
            if p.name < me.name:
                return p
        return None

    @staticmethod
    def _ahead(me: MyView) -> F64:
        """This rover's position and its plan from the point nearest it."""
        pts, s = _resample(me.plan, 0.25)
        return np.vstack([[me.pose.x, me.pose.y], pts[s >= me.start_s_m]])

    def _hold_distance(self, me: MyView, zone: Passage, other: PeerTrack) -> float:
        """How far before the passage to hold: the spot in ``stop_before_m``..``wait_back_m``
        clearest of ``other``'s way (the first with a rover's width and a margin to spare)."""
        cfg = self.cfg
        pts, s = _resample(me.plan, SAMPLE_M)
        s = s - me.start_s_m
        theirs = other.points()
        need = self.robot_width_m + 0.35
        best, best_d = cfg.stop_before_m, -1.0
        for back in np.arange(cfg.stop_before_m, cfg.wait_back_m + 1e-9, 0.2):
            at = zone.s_in_m - float(back)
            if at < 0.0:
                break
            k = int(np.searchsorted(s, at))
            if k >= len(pts):
                continue
            clear = float(_dist_to_polyline(pts[k:k + 1], theirs)[0]) if len(theirs) > 1 else \
                float(np.hypot(*(pts[k] - theirs[0])))
            if clear >= need:
                return float(back)
            if clear > best_d:
                best, best_d = float(back), clear
        return best


def _same(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) < SAME_ZONE_M


def _peer_heading(peer: PeerTrack, plan: F64, plan_d: F64) -> float | None:
    """The direction ``peer`` travels at the passage (its resampled plan ``plan`` and their
    distances to the passage ``plan_d``), or None."""
    if len(plan) >= 2 and len(plan_d):
        k = int(np.argmin(plan_d))
        a = plan[max(0, k - 3)]
        b = plan[min(len(plan) - 1, k + 3)]
        if math.hypot(*(b - a)) > 1e-3:
            return math.atan2(float(b[1] - a[1]), float(b[0] - a[0]))
    if peer.speed_mps > 0.05:
        return peer.pose.yaw
    return None


def eta_s(points: F64, yaw_rad: float, zone: Passage) -> float:
    """Estimated seconds for a rover at ``points[0]`` heading ``yaw_rad`` to reach ``zone``
    along the polyline ``points``: the distance at ``NOMINAL_SPEED_MPS`` plus
    ``TURN_S_PER_RAD`` for every radian it has to turn on the way (Curio turns in place and
    lets its steering settle, so turns cost time). The polyline is resampled every
    ``ETA_STEP_M`` so that sparse and dense plans, sharp and smoothed corners count alike."""
    pts, s = _resample(np.asarray(points, dtype=np.float64), ETA_STEP_M)
    if len(pts) < 2:
        return float(zone.distance(pts)[0]) / NOMINAL_SPEED_MPS if len(pts) else 0.0
    k = max(1, int(np.argmin(zone.distance(pts))))
    legs = np.diff(pts[:k + 1], axis=0)
    headings = np.arctan2(legs[:, 1], legs[:, 0])
    turns = np.abs(np.angle(np.exp(1j * np.diff(np.concatenate([[yaw_rad], headings])))))
    turning = float(turns[turns > 0.1].sum())
    return float(s[k]) / NOMINAL_SPEED_MPS + TURN_S_PER_RAD * turning


def clear_eta_s(peer: PeerTrack, zone: Passage, clear_after_m: float) -> float:
    """Estimated seconds until ``peer`` has driven through ``zone`` and ``clear_after_m``
    beyond it (:func:`eta_s` to the passage, then its length and the margin at
    ``NOMINAL_SPEED_MPS``)."""
    through_m = max(0.0, zone.s_out_m - zone.s_in_m) + clear_after_m
    return eta_s(peer.points(), peer.pose.yaw, zone) + through_m / NOMINAL_SPEED_MPS


# --- the part ---------------------------------------------------------------------------------

class TrafficNode:
    """The rover's traffic part (see the module docstring).

    Args:
        cfg: ``fleet.traffic``.
        me: this rover's name.
        bus, clock: injected.
        finder: narrow passages on the static map.
        robot_width_m, robot_radius_m: the footprint's width and circumscribed radius.
        goal_active: whether the navigator has a goal.
    """

    def __init__(self, cfg: FleetTrafficConfig, me: str, bus: Bus, clock: Clock,
                 finder: PassageFinder, robot_width_m: float, robot_radius_m: float,
                 goal_active: Callable[[], bool]) -> None:
        self.cfg = cfg
        self.me = me
        self.bus = bus
        self.clock = clock
        self.peers = PeerTable(me)
        self.rule = RightOfWay(cfg, finder, robot_width_m)
        self.robot_radius_m = robot_radius_m
        self.goal_active = goal_active
        self.decision = Decision()
        self._plan_xy: F64 = np.zeros((0, 2))
        self._plan_stamp: float | None = None
        self._start_s = 0.0
        self._holding_since: float | None = None
        self._waiting = False
        self.yields = 0
        self.longest_wait_s = 0.0

    # --- inputs -----------------------------------------------------------------------------
    def on_peer(self, name: str, msg: dict[str, Any]) -> None:
        """A traffic message from another rover (loop thread)."""
        self.peers.update(name, msg)

    def _refresh_plan(self, pose: Pose2D) -> None:
        plan = self.bus.latest(PLAN)
        if plan is None or not plan.poses:
            self._plan_xy = np.zeros((0, 2))
            self._plan_stamp = None
            return
        if plan.stamp != self._plan_stamp:
            self._plan_stamp = plan.stamp
            self._plan_xy = np.array([[p.x, p.y] for p in plan.poses], dtype=np.float64)
        xy = self._plan_xy
        d = np.hypot(xy[:, 0] - pose.x, xy[:, 1] - pose.y)
        k = int(np.argmin(d))
        seg = np.hypot(np.diff(xy[:k + 1, 0]), np.diff(xy[:k + 1, 1]))
        self._start_s = float(seg.sum())

    # --- the rule ---------------------------------------------------------------------------
    def step(self) -> Decision:
        """Run the rule once on the latest pose, plan and peers."""
        pose_msg = self.bus.latest(POSE)
        goal = self.goal_active()
        if pose_msg is None:
            return self.decision
        self._refresh_plan(pose_msg.pose)
        view = MyView(self.me, pose_msg.pose, self._plan_xy, self._start_s, goal)
        fresh = self.peers.fresh(self.clock.wall_time(), self.cfg.peer_timeout_s)
        before = self.decision
        self.decision = self.rule.step(view, fresh)
        self._announce(before, self.decision)
        return self.decision

    def _announce(self, before: Decision, after: Decision) -> None:
        if after.state == before.state and after.yield_to == before.yield_to:
            return
        now = self.clock.now()
        if after.state == "yield":
            self.yields += 1
            c = after.zone.centre if after.zone else (0.0, 0.0)
            self._event("traffic.yield", to=after.yield_to, x=c[0], y=c[1],
                        hold_before_m=round(after.hold_s_m, 2))
        elif after.state == "go" and after.zone is not None:
            c = after.zone.centre
            self._event("traffic.go", x=c[0], y=c[1])
        if before.state == "yield" and after.state != "yield":
            waited = now - self._holding_since if self._holding_since is not None else 0.0
            self.longest_wait_s = max(self.longest_wait_s, waited)
            self._event("traffic.resume", waited_s=round(waited, 2), after=before.yield_to)
            self._holding_since = None
            self._waiting = False

    def _event(self, kind: str, **detail: Any) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, detail))

    def speed_limit(self, pose: Pose2D) -> float:
        """The controller's speed limit, m/s (``inf``: none): a rover giving way slows on its
        way to the staging point so that it gets there about ``slow_approach_lead_s`` before
        the other will have cleared the passage (:func:`clear_eta_s`), instead of standing in
        front of the passage for the other's whole approach; never below
        ``SLOW_APPROACH_MIN_MPS``. Off with ``slow_approach_lead_s = 0``."""
        d = self.decision
        lead = self.cfg.slow_approach_lead_s
        if not self.cfg.enabled or lead <= 0.0 or d.state != "yield" or d.zone is None or \
                d.inside or d.yield_to is None:
            return math.inf
        to_staging_m = d.zone.s_in_m - d.hold_s_m
        other = self.peers.peers.get(d.yield_to)
        if to_staging_m <= 0.0 or other is None:
            return math.inf
        spare_s = clear_eta_s(other, d.zone, self.cfg.clear_after_m) - lead
        if spare_s <= 0.0:
            return math.inf
        return max(SLOW_APPROACH_MIN_MPS, to_staging_m / spare_s)

    def hold(self, pose: Pose2D, now: float) -> str | None:
        """The navigator's hook: why to hold still now, or None (drive on)."""
        d = self.decision
        if not self.cfg.enabled or d.state != "yield" or d.zone is None or d.inside:
            return None
        if d.zone.s_in_m > d.hold_s_m:
            return None
        if self._holding_since is None:
            self._holding_since = now
        odom = self.bus.latest(ODOM)
        if not self._waiting and odom is not None and abs(odom.linear_mps) < WAIT_SPEED_MPS:
            self._waiting = True
            self._event("traffic.waiting", to=d.yield_to)
        self.longest_wait_s = max(self.longest_wait_s, now - self._holding_since)
        return f"giving way to {d.yield_to} at a narrow passage"

    @property
    def holding(self) -> bool:
        """Whether the rover is holding for another rover now."""
        return self._holding_since is not None and self.decision.state == "yield"

    def message(self, plan_step_m: float = 0.4) -> dict[str, Any]:
        """This rover's traffic message (for ``curio/<rover>/traffic``): the plan ahead every
        ``plan_step_m``, to the centimetre."""
        pose_msg = self.bus.latest(POSE)
        odom = self.bus.latest(ODOM)
        pose = pose_msg.pose if pose_msg is not None else Pose2D()
        ahead: list[list[float]] = []
        if len(self._plan_xy) >= 2:
            pts, s = _resample(self._plan_xy, plan_step_m)
            keep = (s >= self._start_s) & (s <= self._start_s + self.cfg.lookahead_m)
            ahead = [[round(float(x), 2), round(float(y), 2)] for x, y in pts[keep]]
        d = self.decision
        return {"t": self.clock.wall_time(), "x": pose.x, "y": pose.y, "yaw": pose.yaw,
                "v": odom.linear_mps if odom is not None else 0.0,
                "goal": self.goal_active(), "plan": ahead, "state": d.state,
                "zone": list(d.zone.centre) if d.zone is not None else None,
                "yield": d.yield_to, "inside": d.inside, "r": self.robot_radius_m,
                "stop_in": self._stop_in(d)}

    @staticmethod
    def _stop_in(d: Decision) -> float | None:
        """Yielding: how far (m, along the plan) it drives on before it holds (None: it does
        not hold; curio/fleet/intent.py predicts the others with it)."""
        if d.state != "yield" or d.zone is None or d.inside:
            return None
        return round(max(0.0, d.zone.s_in_m - d.hold_s_m), 2)

    async def run(self) -> None:
        """Run the rule at ``rate_hz`` until cancelled."""
        async for _ in self.clock.every(1.0 / self.cfg.rate_hz, phase_s=0.013):
            try:
                self.step()
            except Exception:  # the rule must never take the rover down
                log.exception("traffic: the right-of-way step failed; holding nothing")
                self.decision = Decision()
