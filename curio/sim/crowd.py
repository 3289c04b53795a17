"""The simulated crowd: visitors moved by the social-force model (Helbing & Molnár 1995).

:class:`Crowd` owns the visitors' positions and velocities (``map``, metres, m/s) and steps
them at ``sim.crowd.rate_hz`` (the world calls :meth:`Crowd.step` from its physics step):

1. each visitor's plan (:mod:`curio.sim.visitors`) gives its desired velocity (towards the
   next point of its route, zero while standing);
2. the compiled social forces (:mod:`curio.sim.crowd_kernel`) add repulsion from the other
   visitors, the walls and the rover *as the visitor last perceived it* (each looks at the
   rover every ``reaction_s``; a distracted one only notices it within ``notice_m``);
3. speeds are capped at 1.3 × the desired speed; a step that would take a visitor into a wall
   is refused, and so is one that would overlap the rover's footprint: the visitor stops
   against the rover and a ``collision`` event is raised once per contact, ``fault:
   "rover"`` when the rover's own motion (forward and turning) was bringing its footprint
   nearer to them faster than 0.05 m/s (``curio.safety.stop_zone.ROVER_CLOSING_MPS``, the
   rule the close-pass metrics use), ``"person"`` otherwise: standing still, moving or
   turning away.

The simulated lidar sees each visitor as two legs (radius 0.06 m, 0.2 m apart, swinging
with the gait) or one body circle (``sim.crowd.lidar_model``). Everything random comes from
the generator given at construction (deterministic for a seed).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from curio.core.config import Config, CrowdConfig
from curio.core.geometry import Pose2D
from curio.core.messages import SimPeople, SimPerson
from curio.estimation.maps import OccupancyGrid
from curio.robot import footprint_radii
from curio.safety.stop_zone import ROVER_CLOSING_MPS, closing_speeds_mps
from curio.sim.crowd_kernel import (
    cast_discs,
    count_hits,
    crowd_advance,
    crowd_inputs,
    social_accelerations,
)
from curio.sim.visitors import (
    ARRIVE_M,
    ASIDE_S,
    FOLLOW_STAND_M,
    STEER_PERIOD_S,
    STUCK_S,
    Planner,
    Visitor,
)
from curio.sim.walkmap import WalkMap

__all__ = ["Crowd", "RoverState"]

F64 = npt.NDArray[np.float64]
Point = tuple[float, float]

# Helbing & Molnár (1995): V0 = 2.1 m²/s², σ = 0.3 m, Δt = 2 s, U0 = 10 m²/s², R = 0.2 m,
# τ = 0.5 s, field of view 2φ = 200°, c = 0.5. People give the rover (a machine) a wider berth
# than each other: its potential is 2.5 × a person's.
SF_PARAMS = np.array([2.1, 0.3, 2.0, 10.0, 0.2, math.cos(math.radians(100.0)), 0.5, 5.0, 2.5])
TAU_S = 0.5
LEG_RADIUS_M = 0.06
LEG_OFFSET_M = 0.1
STRIDE_M = 1.3
SWING_M = 0.15
VISIBLE_MARGIN_M = 0.1
PLAN_PERIOD_S = 0.2  # plans (destinations, where to head) move on at 5 Hz


@dataclass(frozen=True)
class RoverState:
    """The rover as the crowd sees it: pose in ``map``, body velocity (m/s, rad/s) and its
    footprint (``(E, 2)`` polygon in ``base_link``, m)."""

    pose: Pose2D
    linear_mps: float
    angular_radps: float
    footprint: F64

    def closing_mps(self, x: float, y: float) -> float:
        """How fast the rover's own motion brings its footprint nearer to ``(x, y)`` (``map``,
        m), m/s (negative: farther)."""
        return float(closing_speeds_mps(self.footprint, self.pose, self.linear_mps,
                                        self.angular_radps, np.array([[x, y]]))[0])

    @property
    def velocity(self) -> Point:
        """Velocity of the rover's centre in ``map``, m/s."""
        return (self.linear_mps * math.cos(self.pose.yaw),
                self.linear_mps * math.sin(self.pose.yaw))


class Crowd:
    """Visitors walking a world (see the module docstring).

    Args:
        walk: the world's walking geometry.
        cfg: ``sim.crowd``.
        rng: the crowd's random generator.
        pois: points of interest (map metres).
        rover_start: where the rover starts (no visitor starts within 2 m of it).
        rover_radius_m: the circle round the rover's footprint that visitors keep out of
            (its circumscribed radius, m).
        first_id: the first visitor id.
    """

    def __init__(self, walk: WalkMap, cfg: CrowdConfig, rng: np.random.Generator,
                 pois: list[Point], rover_start: Point, rover_radius_m: float,
                 first_id: int = 1) -> None:
        self.walk = walk
        self.cfg = cfg
        self.rng = rng
        self.planner = Planner(walk, pois, cfg, rng)
        self.visitors: list[Visitor] = self.planner.make_visitors(cfg.visitors, first_id)
        n = len(self.visitors)
        self.pos: F64 = np.zeros((n, 2))
        self.vel: F64 = np.zeros((n, 2))
        self.steer: F64 = np.zeros((n, 2))  # where each visitor heads (map)
        self.speed: F64 = np.zeros(n)  # at what speed (m/s; 0: standing)
        self.heading: F64 = rng.uniform(-math.pi, math.pi, n)
        self.phase: F64 = rng.uniform(0.0, 2.0 * math.pi, n)
        self.cap: F64 = np.array([1.3 * max(v.v0, 0.5) for v in self.visitors])
        self._attention = np.array([v.attention for v in self.visitors], dtype=np.float64)
        self._notice = np.array([v.notice_m for v in self.visitors], dtype=np.float64)
        self._reaction = np.array([v.reaction_s for v in self.visitors], dtype=np.float64)
        self._seen_at = np.full(n, -np.inf)
        self._seen = np.zeros((n, 5))
        self._seen[:, 4] = rover_radius_m
        self._plan_due_s = 0.0
        self.radius_m = cfg.body_radius_m
        self.time_s = 0.0
        self._acc = np.zeros((n, 2))
        # Scratch for the compiled step (crowd_inputs → social_accelerations → crowd_advance).
        self._desired = np.zeros((n, 2))
        self._walls = np.zeros((n, 3))
        self._here_clear = np.zeros(n)
        self._weight = np.zeros(n)
        self._near = np.zeros(n, dtype=np.bool_)
        self._pending_s = 0.0
        self.contacts = 0
        self._place(rover_start)
        self._visible = np.zeros(n, dtype=np.int64)

    @classmethod
    def for_world(cls, grid: OccupancyGrid, cfg: Config, start: Pose2D,
                  first_id: int = 1) -> Crowd | None:
        """The crowd ``cfg.sim.crowd`` asks for on ``grid`` (None without visitors)."""
        ccfg = cfg.sim.crowd
        if ccfg.visitors <= 0:
            return None
        rng = np.random.default_rng([cfg.sim.seed, 0xC40D])
        walk = WalkMap(grid, walk_clearance_m=ccfg.body_radius_m + 0.05,
                       anchor=(start.x, start.y))
        given = list(ccfg.pois) or [(s.x_m, s.y_m) for s in cfg.bt.tour_stops]
        pois = walk.points_of_interest(rng, given)
        _inscribed, circumscribed = footprint_radii(np.asarray(cfg.robot.footprint))
        return cls(walk, ccfg, rng, pois, (start.x, start.y), circumscribed, first_id)

    # -- set-up ------------------------------------------------------------------------------
    def _place(self, rover_start: Point) -> None:
        spots = self.walk.spawn_points(self.rng, len(self.visitors), rover_start)
        while len(spots) < len(self.visitors):  # a tiny map: share spots, a little apart
            x, y = spots[len(spots) % max(1, len(spots))] if spots else rover_start
            spots.append(self.planner.stand_point((x, y), 0.5))
        by_id: dict[int, Visitor] = {}
        for i, v in enumerate(self.visitors):
            self.pos[i] = spots[i]
            by_id[v.vid] = v
        # Group members start next to their first member.
        for group in self.planner.groups.values():
            head = self._index(group.members[0])
            for k, m in enumerate(group.members[1:], start=1):
                spot = (self.pos[head, 0] + 0.6 * k, self.pos[head, 1])
                if self.walk.clearance_at(np.array([spot]))[0] >= 0.35:
                    self.pos[self._index(m)] = spot
        positions = self._positions()
        for gid in self.planner.groups:
            self.planner.send_group(gid, 0.0, positions, by_id)
        for v in self.visitors:
            if v.group < 0:
                self.planner.start(v, 0.0, positions[v.vid])
        self.steer[:] = self.pos

    def _index(self, vid: int) -> int:
        return vid - self.visitors[0].vid

    def _positions(self) -> dict[int, Point]:
        return {v.vid: (p[0], p[1]) for v, p in zip(self.visitors, self.pos.tolist(), strict=True)}

    @property
    def following(self) -> bool:
        """Whether a guided tour runs (followers follow the rover)."""
        return self.planner.following

    @following.setter
    def following(self, value: bool) -> None:
        self.planner.following = value

    # -- stepping ----------------------------------------------------------------------------
    def step(self, dt_s: float, rover: RoverState,
             touches: Callable[[float, float, float], bool]) -> list[dict[str, Any]]:
        """Advance by ``dt_s`` (updates at ``rate_hz``); return contact events' details."""
        self._pending_s += dt_s
        period = 1.0 / self.cfg.rate_hz
        events: list[dict[str, Any]] = []
        while self._pending_s >= period - 1e-9:
            self._pending_s -= period
            self.time_s += period
            events += self._update(period, rover, touches)
        return events

    def _update(self, dt: float, rover: RoverState,
                touches: Callable[[float, float, float], bool]) -> list[dict[str, Any]]:
        now = self.time_s
        if now >= self._plan_due_s:
            self._plan_due_s = now + PLAN_PERIOD_S
            self._plan(now, rover)
        self._perceive(now, rover)
        walk = self.walk
        rx, ry = rover.pose.x, rover.pose.y
        # Desired velocities, the nearest walls and how strongly each avoids the rover.
        crowd_inputs(self.pos, self.steer, self.speed, rx, ry, self._notice, self._attention,
                     walk.clearance_fine, walk.near_row, walk.near_col, walk.ox, walk.oy,
                     walk.res_fine, self._desired, self._walls, self._here_clear, self._weight)
        social_accelerations(self.pos, self.vel, self._desired, TAU_S, self._walls, self._seen,
                             self._weight, SF_PARAMS, self._acc)
        # Speeds capped; a step into a wall is refused.
        new = np.empty_like(self.pos)
        vel = np.empty_like(self.vel)
        crowd_advance(self.pos, self.vel, self._acc, dt, self.cap, self._here_clear,
                      0.8 * self.radius_m, walk.clearance_fine, walk.near_row, walk.near_col,
                      walk.ox, walk.oy, walk.res_fine, rx, ry, 0.5 + self.radius_m + 0.2, new,
                      vel, self._near)
        events = self._rover_contacts(new, vel, rover, touches, self._near)
        self._gait(vel, dt)
        self.pos, self.vel = new, vel
        return events

    def _perceive(self, now: float, rover: RoverState) -> None:
        """The visitors due to look at the rover again (every ``reaction_s``) see it now
        (``_seen``: x, y, vx, vy in ``map``; its radius)."""
        due = now - self._seen_at >= self._reaction
        if due.any():
            vx, vy = rover.velocity
            self._seen[due, :4] = (rover.pose.x, rover.pose.y, vx, vy)
            self._seen_at[due] = now

    def _rover_contacts(self, new: F64, vel: F64, rover: RoverState,
                        touches: Callable[[float, float, float], bool],
                        near: npt.NDArray[np.bool_]) -> list[dict[str, Any]]:
        """Refuse steps into the rover (``near``: the steps ending within 0.7 m + a body
        radius of its centre); one event per contact, with whose fault it is."""
        events: list[dict[str, Any]] = []
        rx, ry = rover.pose.x, rover.pose.y
        for i in np.flatnonzero(near):
            v = self.visitors[i]
            if not touches(float(new[i, 0]), float(new[i, 1]), self.radius_m):
                if v.in_contact and not touches(float(new[i, 0]), float(new[i, 1]),
                                                self.radius_m + 0.05):
                    v.in_contact = False
                continue
            was = touches(float(self.pos[i, 0]), float(self.pos[i, 1]), self.radius_m)
            d_new = math.hypot(new[i, 0] - rx, new[i, 1] - ry)
            d_old = math.hypot(self.pos[i, 0] - rx, self.pos[i, 1] - ry)
            if was and d_new > d_old:
                continue  # already touching (placed there): moving away is allowed
            new[i] = self.pos[i]
            vel[i] = 0.0
            if not v.in_contact:
                v.in_contact = True
                self.contacts += 1
                closing = rover.closing_mps(float(self.pos[i, 0]), float(self.pos[i, 1]))
                fault = "rover" if closing > ROVER_CLOSING_MPS else "person"
                events.append({"with": [f"visitor:{v.vid}"], "fault": fault,
                               "by": "person", "x": round(rx, 3), "y": round(ry, 3),
                               "yaw": round(rover.pose.yaw, 3),
                               "speed_mps": round(rover.linear_mps, 3),
                               "person_xy": [round(float(self.pos[i, 0]), 3),
                                             round(float(self.pos[i, 1]), 3)]})
        return events

    def _gait(self, vel: F64, dt: float) -> None:
        sp = np.hypot(vel[:, 0], vel[:, 1])
        moving = sp > 0.15
        self.heading[moving] = np.arctan2(vel[moving, 1], vel[moving, 0])
        self.phase = (self.phase + 2.0 * math.pi * sp * dt / STRIDE_M) % (2.0 * math.pi)

    # -- plans -------------------------------------------------------------------------------
    def _plan(self, now: float, rover: RoverState) -> None:
        """Move every visitor's plan on: where it heads (``steer``) and how fast (``speed``)."""
        by_id = {v.vid: v for v in self.visitors}
        positions: dict[int, Point] | None = None
        for gid, group in self.planner.groups.items():
            members = [by_id[m] for m in group.members]
            standing = [m.state == "standing" for m in members]
            if group.arrived_s is None and any(standing):
                group.arrived_s = now
            if (group.arrived_s is not None and group.dwell_until_s == math.inf
                    and (all(standing) or now - group.arrived_s > 20.0)):
                group.dwell_until_s = now + float(self.rng.uniform(self.cfg.dwell_min_s,
                                                                   self.cfg.dwell_max_s))
            if now >= group.dwell_until_s and all(m.state != "stepping_aside" for m in members):
                positions = positions or self._positions()
                self.planner.send_group(gid, now, positions, by_id)
        xy = self.pos.tolist()
        for i, v in enumerate(self.visitors):
            here = (xy[i][0], xy[i][1])
            target, speed = self._intent(v, here, now, rover)
            if speed > 0.0 and self._give_way(i, v, here, target, now):
                target, speed = self._wait_spot(i, here), 0.4
                v.progress_ref = (here[0], here[1], now)  # waiting is not being stuck
            self.steer[i] = target
            self.speed[i] = speed
            if speed == 0.0 and v.face is not None:
                self.heading[i] = math.atan2(v.face[1] - here[1], v.face[0] - here[0])
        self._group_pace()

    def _intent(self, v: Visitor, here: Point, now: float,
                rover: RoverState) -> tuple[Point, float]:
        """Where ``v`` heads now and at what speed (0: it stands)."""
        if v.state == "stepping_aside":
            if now >= v.aside_until_s or math.dist(here, v.target) < ARRIVE_M:
                v.state = v.resume_state
                v.steer_due_s = now
            else:
                return v.target, 0.7
        if v.behaviour == "follower" and self.planner.following:
            return self._follow(v, here, now, rover)
        if v.state == "standing":
            if now >= v.dwell_until_s and v.group < 0:
                self.planner.start(v, now, here)
            return here, 0.0
        return self._walk(v, here, now)

    def _give_way(self, i: int, v: Visitor, here: Point, target: Point, now: float) -> bool:
        """Whether an attentive visitor waits because the rover (as last seen) stands in
        their way, within 1.8 m ahead; they wait ``patience_s``, then walk on round it (and
        do not wait for it again for 15 s)."""
        if now < v.bold_until_s:
            return False
        rx, ry = float(self._seen[i, 0]), float(self._seen[i, 1])
        d = math.hypot(rx - here[0], ry - here[1])
        tx, ty = target[0] - here[0], target[1] - here[1]
        n = math.hypot(tx, ty)
        reach = 1.8 if v.waiting_since_s is None else 2.5  # hysteresis
        in_way = (math.isinf(v.notice_m) and 1e-6 < d < reach and n > 1e-6
                  and (tx * (rx - here[0]) + ty * (ry - here[1])) / (n * d) > 0.6)
        if not in_way:
            v.waiting_since_s = None
            return False
        if v.waiting_since_s is None:
            v.waiting_since_s = now
            v.patience_s = float(self.rng.uniform(3.0, 10.0))
        if now - v.waiting_since_s < v.patience_s:
            return True
        v.waiting_since_s = None
        v.bold_until_s = now + 15.0
        return False

    def _wait_spot(self, i: int, here: Point) -> Point:
        """Where to wait for the rover: here, or a little back if nearer than 1.4 m."""
        rx, ry = float(self._seen[i, 0]), float(self._seen[i, 1])
        d = math.hypot(here[0] - rx, here[1] - ry)
        if d >= 1.4 or d < 1e-6:
            return here
        return (here[0] + (here[0] - rx) / d * (1.4 - d), here[1] + (here[1] - ry) / d * (1.4 - d))

    def _walk(self, v: Visitor, here: Point, now: float) -> tuple[Point, float]:
        dist = math.dist(here, v.target)
        if dist < ARRIVE_M:
            v.state = "standing"
            if v.group < 0:
                lo, hi = (0.0, 1.0) if v.behaviour == "crosser" else (2.0, 10.0)
                v.dwell_until_s = now + float(self.rng.uniform(lo, hi))
            return here, 0.0
        if math.dist(here, v.progress_ref[:2]) > 0.3:
            v.progress_ref = (here[0], here[1], now)
        elif now - v.progress_ref[2] > STUCK_S:
            if v.group < 0:
                self.planner.start(v, now, here)
            else:
                v.target = self.planner.stand_point(here, 0.3)  # give up the slot
            v.progress_ref = (here[0], here[1], now)
        if now >= v.steer_due_s and v.tree is not None:
            v.steer_due_s = now + STEER_PERIOD_S
            if dist < 3.0 and self.walk.segment_clear(here, v.target, 0.2):
                v.steer = v.target
            else:
                v.steer = self.walk.steer_point(v.tree, here[0], here[1])
        return v.steer, v.v0 * min(1.0, 0.3 + dist / 1.0)

    def _follow(self, v: Visitor, here: Point, now: float,
                rover: RoverState) -> tuple[Point, float]:
        rx, ry = rover.pose.x, rover.pose.y
        d = math.hypot(rx - here[0], ry - here[1])
        stand = FOLLOW_STAND_M[0] + (v.vid % 5) * 0.1
        v.face = (rx, ry)
        if d <= stand:
            v.state = "standing"
            return here, 0.0
        v.state = "walking"
        if now >= v.steer_due_s:
            v.steer_due_s = now + STEER_PERIOD_S
            if d < 4.0 and self.walk.segment_clear(here, (rx, ry), 0.2):
                v.steer = (rx, ry)
            else:
                v.steer = self.walk.steer_point(self.planner.rover_tree((rx, ry), now),
                                                here[0], here[1])
        return v.steer, v.v0 * min(1.0, (d - stand) / 1.0)

    def _group_pace(self) -> None:
        """Walking group members keep together: the pace of the group, the one ahead waits."""
        for group in self.planner.groups.values():
            idx = [self._index(m) for m in group.members]
            walking = [i for i in idx if self.visitors[i].state == "walking"]
            if len(walking) < 2:
                continue
            centre = self.pos[idx].mean(axis=0)
            for i in walking:
                to = self.steer[i] - self.pos[i]
                n = math.hypot(to[0], to[1])
                if n < 1e-6:
                    continue
                ahead = float(np.dot(self.pos[i] - centre, to / n))
                pace = group.speed * (0.5 if ahead > 1.2 else 1.25 if ahead < -1.5 else 1.0)
                self.speed[i] = min(self.speed[i], pace)

    # -- the rover speaks --------------------------------------------------------------------
    def hear_excuse_me(self, rover: Pose2D, now_s: float | None = None,
                       radius_m: float = 3.5) -> list[int]:
        """Visitors in front of the rover (within ``radius_m``, ±75°) step aside with
        ``excuse_me_compliance``; return their ids."""
        now = self.time_s if now_s is None else now_s
        c, s = math.cos(rover.yaw), math.sin(rover.yaw)
        moved = []
        for i, v in enumerate(self.visitors):
            dx, dy = self.pos[i, 0] - rover.x, self.pos[i, 1] - rover.y
            d = math.hypot(dx, dy)
            if d > radius_m or (c * dx + s * dy) < d * math.cos(math.radians(75.0)):
                continue
            p = self.cfg.excuse_me_compliance * (1.2 if v.behaviour == "follower" else 1.0)
            if v.state == "stepping_aside" or self.rng.random() >= p:
                continue
            spot = self.planner.aside_point((float(self.pos[i, 0]), float(self.pos[i, 1])),
                                            (rover.x, rover.y, rover.yaw))
            if spot is None:
                continue
            if v.state == "walking":
                v.steer, v.steer_due_s = spot, now + 3.0  # a detour, then on its way
            else:
                v.resume_state, v.state, v.target = "standing", "stepping_aside", spot
                v.aside_until_s = now + ASIDE_S
            moved.append(v.vid)
        return moved

    # -- what others see -------------------------------------------------------------------
    def lidar_circles(self) -> F64:
        """``(M, 3)`` circles (x, y, radius) the lidar sees: two legs or one body each."""
        n = len(self.visitors)
        if self.cfg.lidar_model == "body":
            return np.column_stack([self.pos, np.full(n, self.radius_m)])
        c, s = np.cos(self.heading), np.sin(self.heading)
        sp = np.hypot(self.vel[:, 0], self.vel[:, 1])
        swing = SWING_M * np.minimum(1.0, sp) * np.sin(self.phase)
        out = np.empty((2 * n, 3))
        for k, sign in enumerate((1.0, -1.0)):
            out[k::2, 0] = self.pos[:, 0] + sign * (c * swing - s * LEG_OFFSET_M)
            out[k::2, 1] = self.pos[:, 1] + sign * (s * swing + c * LEG_OFFSET_M)
            out[k::2, 2] = LEG_RADIUS_M
        return out

    def touching(self, inside: Callable[[float, float, float], bool],
                 centre: Point, reach_m: float) -> list[str]:
        """Ids (``visitor:<id>``) of the visitors whose body ``inside(x, y, r)`` says touches
        a shape centred at ``centre`` reaching ``reach_m``."""
        d = np.hypot(self.pos[:, 0] - centre[0], self.pos[:, 1] - centre[1])
        return [f"visitor:{self.visitors[i].vid}" for i in np.flatnonzero(
            d <= reach_m + self.radius_m)
            if inside(float(self.pos[i, 0]), float(self.pos[i, 1]), self.radius_m)]

    def cast(self, ox: float, oy: float, dx: F64, dy: F64, ranges: F64) -> None:
        """Shorten ``ranges`` (m, in place) of rays from (ox, oy) along unit (dx, dy) (map)
        where they hit a visitor first (legs or body, ``sim.crowd.lidar_model``)."""
        if self.visitors:
            cast_discs(ox, oy, dx, dy, self.lidar_circles(), ranges)

    def note_scan(self, endpoints: F64) -> None:
        """Count the returns of the latest scan (``(K, 2)`` map points) that hit each visitor."""
        count_hits(np.ascontiguousarray(endpoints, dtype=np.float64), self.pos,
                   self.radius_m + VISIBLE_MARGIN_M, self._visible)

    def truth(self, stamp: float) -> SimPeople:
        """Every visitor's ground truth (``/people/ground_truth``)."""
        pos, vel, visible = self.pos.tolist(), self.vel.tolist(), self._visible.tolist()
        return SimPeople(stamp, tuple(
            SimPerson(v.vid, p[0], p[1], u[0], u[1], self.radius_m, v.behaviour, v.group,
                      v.state, n)
            for v, p, u, n in zip(self.visitors, pos, vel, visible, strict=True)))
