"""What simulated visitors want to do: behaviours, destinations, groups, standing and stepping
aside (the *plans*; the social-force physics that moves them is :mod:`curio.sim.crowd`).

Each visitor has a behaviour (``sim.crowd.mix_*``):

* **wanderer** — walks to a random point of interest, looks at it for 2–10 s, walks on;
* **group** — 2–4 visitors who walk together (the slowest sets the pace; the one ahead waits,
  the one behind hurries) to an exhibit, stand round it on an arc on the side they came from
  for ``dwell_min_s`` .. ``dwell_max_s``, then walk on together;
* **crosser** — walks fast to a far point of interest (across corridors and through doorways)
  and on at once;
* **follower** — during a guided tour follows the rover and stands 1.2–1.6 m from it when it
  stops; a wanderer otherwise.

An attentive visitor whose way the rover blocks (it stands within 1.8 m ahead on the
visitor's route) waits for it — 3 to 10 s — and then walks on round it as best they can.
Asked "Excuse me" by the rover, a visitor in front of it steps aside (with
``excuse_me_compliance``) and stays there for a while. All positions are in ``map``, metres;
every random draw comes from the crowd's generator (deterministic for a seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from curio.core.config import CrowdConfig
from curio.sim.walkmap import WalkMap, _Tree

__all__ = ["BEHAVIOURS", "Planner", "Visitor"]

Point = tuple[float, float]
BEHAVIOURS = ("wanderer", "group", "crosser", "follower")
ARRIVE_M = 0.3  # a stand point is reached this near
STEER_PERIOD_S = 0.5  # how often a walking visitor re-reads its route
STUCK_S = 12.0  # no 0.3 m of progress for this long: choose somewhere else
FOLLOW_STAND_M = (1.3, 1.7)  # followers stop this far from the rover (centre to centre)
ASIDE_M = 0.9
ASIDE_S = 6.0


@dataclass
class Visitor:
    """One visitor's intentions and perception (the positions live in the crowd's arrays).

    Attributes:
        vid: id in the world (``visitor:<vid>``).
        behaviour: one of :data:`BEHAVIOURS`.
        v0: desired walking speed, m/s.
        attention: how strongly the visitor avoids the rover (0..1).
        notice_m: the visitor reacts to the rover only within this distance (distracted).
        reaction_s: delay between two looks at the rover, seconds.
        state: ``walking``, ``standing`` or ``stepping_aside``.
    """

    vid: int
    behaviour: str
    v0: float
    attention: float
    notice_m: float
    reaction_s: float
    group: int = -1
    slot: int = 0
    state: str = "walking"
    dest: int = -1
    target: Point = (0.0, 0.0)
    face: Point | None = None
    tree: _Tree | None = None
    steer: Point = (0.0, 0.0)
    steer_due_s: float = 0.0
    dwell_until_s: float = math.inf
    aside_until_s: float = 0.0
    resume_state: str = "walking"
    seen_at_s: float = -math.inf
    seen_rover: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    progress_ref: tuple[float, float, float] = (0.0, 0.0, 0.0)
    in_contact: bool = False
    waiting_since_s: float | None = None  # waiting for the rover to get out of the way
    patience_s: float = 0.0
    bold_until_s: float = -math.inf  # waited long enough: walks round the rover until then


@dataclass
class _Group:
    members: list[int]
    dest: int = -1
    arrived_s: float | None = None
    dwell_until_s: float = math.inf
    speed: float = 1.0


@dataclass
class Planner:
    """Chooses destinations and desired velocities for every visitor.

    Args:
        walk: the world's walking geometry.
        pois: points of interest (map metres).
        cfg: ``sim.crowd``.
        rng: the crowd's random generator.
    """

    walk: WalkMap
    pois: list[Point]
    cfg: CrowdConfig
    rng: np.random.Generator
    groups: dict[int, _Group] = field(default_factory=dict)
    following: bool = False
    _rover_tree: _Tree | None = None
    _rover_tree_due_s: float = 0.0

    # -- set-up ------------------------------------------------------------------------------
    def make_visitors(self, n: int, first_id: int) -> list[Visitor]:
        """``n`` visitors with behaviours in the configured mix (largest remainder)."""
        cfg = self.cfg
        shares = np.array([cfg.mix_wanderer, cfg.mix_group, cfg.mix_crosser, cfg.mix_follower])
        raw = shares / shares.sum() * n
        counts = np.floor(raw).astype(int)
        for k in np.argsort(-(raw - counts), kind="stable")[: n - int(counts.sum())]:
            counts[k] += 1
        kinds = [b for b, c in zip(BEHAVIOURS, counts, strict=True) for _ in range(int(c))]
        out = []
        for i, kind in enumerate(kinds):
            out.append(self._visitor(first_id + i, kind))
        self._form_groups([v for v in out if v.behaviour == "group"])
        return out

    def _visitor(self, vid: int, kind: str) -> Visitor:
        cfg, rng = self.cfg, self.rng
        v0 = float(np.clip(rng.normal(cfg.speed_mean_mps, cfg.speed_sigma_mps),
                           cfg.speed_min_mps, cfg.speed_max_mps))
        if kind == "crosser":
            v0 = float(rng.uniform(max(cfg.speed_min_mps, min(1.1, cfg.speed_max_mps)),
                                   cfg.speed_max_mps))
        distracted = bool(rng.random() < cfg.distracted_fraction) and kind != "follower"
        attention = 0.5 if distracted else float(rng.uniform(0.6, 1.0))
        notice = cfg.distracted_notice_m if distracted else math.inf
        reaction = float(rng.uniform(0.5, 1.5)) * cfg.reaction_time_s
        return Visitor(vid, kind, v0, attention, notice, reaction)

    def _form_groups(self, members: list[Visitor]) -> None:
        cfg, rng = self.cfg, self.rng
        k = 0
        gid = len(self.groups)
        while k < len(members):
            size = int(rng.integers(cfg.group_size_min, cfg.group_size_max + 1))
            if len(members) - k - size == 1:  # no group of one
                size += 1 if size < cfg.group_size_max else -1
            chunk = members[k:k + max(1, size)]
            speed = 0.9 * min(v.v0 for v in chunk)
            self.groups[gid] = _Group([v.vid for v in chunk], speed=speed)
            for slot, v in enumerate(chunk):
                v.group, v.slot = gid, slot
                if len(chunk) == 1:
                    v.behaviour, v.group = "wanderer", -1
            if len(chunk) == 1:
                del self.groups[gid]
            k += len(chunk)
            gid += 1

    # -- destinations ------------------------------------------------------------------------
    def pick_dest(self, here: Point, far: bool = False, avoid: int = -1) -> int:
        """A point of interest: random (not ``avoid``), or the farthest of three."""
        n = len(self.pois)
        if n == 1:
            return 0
        choices = [int(c) for c in self.rng.integers(0, n, size=3 if far else 1)]
        choices = [c for c in choices if c != avoid] or [(avoid + 1) % n]
        if far:
            return max(choices, key=lambda c: math.hypot(self.pois[c][0] - here[0],
                                                         self.pois[c][1] - here[1]))
        return choices[0]

    def stand_point(self, centre: Point, jitter_m: float = 0.6) -> Point:
        """A free point near ``centre`` where a visitor can stand."""
        for _ in range(6):
            ang = float(self.rng.uniform(-math.pi, math.pi))
            rad = float(self.rng.uniform(0.0, jitter_m))
            p = (centre[0] + rad * math.cos(ang), centre[1] + rad * math.sin(ang))
            if self.walk.clearance_at(np.array([p]))[0] >= 0.35:
                return p
        return centre

    def group_slots(self, gid: int, centroid: Point) -> list[Point]:
        """Stand points on an arc round the group's exhibit, on the side it comes from."""
        group = self.groups[gid]
        px, py = self.pois[group.dest]
        base = math.atan2(centroid[1] - py, centroid[0] - px)
        n = len(group.members)
        out = []
        for k in range(n):
            ang = base + (k - (n - 1) / 2.0) * 0.55
            spot = None
            for rad in (1.0, 1.3, 0.7, 1.6):
                p = (px + rad * math.cos(ang), py + rad * math.sin(ang))
                if self.walk.clearance_at(np.array([p]))[0] >= 0.35:
                    spot = p
                    break
            out.append(spot or self.stand_point((px, py), 1.0))
        return out

    def send(self, v: Visitor, dest: int, target: Point, now_s: float, here: Point) -> None:
        """Walk ``v`` to ``target`` (a stand point of point of interest ``dest``)."""
        v.dest = dest
        v.target = target
        v.face = self.pois[dest] if dest >= 0 else None
        # Routes lead to the point of interest (one tree each, kept); the last metres to the
        # stand point beside it are walked in a straight line.
        v.tree = self.walk.tree_to(self.walk.node_at(*self.pois[dest]))
        v.state = "walking"
        v.steer_due_s = now_s
        v.dwell_until_s = math.inf
        v.progress_ref = (here[0], here[1], now_s)

    def send_group(self, gid: int, now_s: float, positions: dict[int, Point],
                   visitors: dict[int, Visitor]) -> None:
        """Choose the group's next exhibit and send every member to its slot."""
        group = self.groups[gid]
        pts = [positions[m] for m in group.members]
        centroid = (float(np.mean([p[0] for p in pts])), float(np.mean([p[1] for p in pts])))
        group.dest = self.pick_dest(centroid, avoid=group.dest)
        group.arrived_s = None
        group.dwell_until_s = math.inf
        for m, slot in zip(group.members, self.group_slots(gid, centroid), strict=True):
            self.send(visitors[m], group.dest, slot, now_s, positions[m])

    def start(self, v: Visitor, now_s: float, here: Point) -> None:
        """Give a lone visitor its first or next destination."""
        dest = self.pick_dest(here, far=v.behaviour == "crosser", avoid=v.dest)
        self.send(v, dest, self.stand_point(self.pois[dest]), now_s, here)

    # -- per update ----------------------------------------------------------------------------
    def rover_tree(self, rover_xy: Point, now_s: float) -> _Tree:
        """A route tree towards the rover (followers), refreshed every 2 s, 25 m deep (the same
        tree while the rover stands on the same node: it is not searched again)."""
        if self._rover_tree is None or now_s >= self._rover_tree_due_s:
            node = self.walk.node_at(*rover_xy)
            if self._rover_tree is None or self._rover_tree.dest != node:
                self._rover_tree = self.walk.tree_to(node, limit_m=25.0)
            self._rover_tree_due_s = now_s + 2.0
        return self._rover_tree

    def aside_point(self, here: Point, rover: tuple[float, float, float]) -> Point | None:
        """Where to step to get out of the rover's way (``rover``: x, y, yaw), or None."""
        rx, ry, yaw = rover
        c, s = math.cos(yaw), math.sin(yaw)
        lat = -s * (here[0] - rx) + c * (here[1] - ry)
        side = 1.0 if lat > 0.05 else -1.0 if lat < -0.05 else (
            1.0 if self.rng.random() < 0.5 else -1.0)
        for sign in (side, -side):
            p = (here[0] - s * sign * ASIDE_M, here[1] + c * sign * ASIDE_M)
            if self.walk.clearance_at(np.array([p]))[0] >= 0.3 and self.walk.segment_clear(
                    here, p, 0.2):
                return p
        back = (here[0] + c * ASIDE_M, here[1] + s * ASIDE_M)
        if self.walk.clearance_at(np.array([back]))[0] >= 0.3:
            return back
        return None
