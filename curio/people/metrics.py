"""Figures against the simulator's ground truth: tracking (CLEAR MOT) and closeness to people.

:class:`MotAccumulator` scores tracks frame by frame with the CLEAR MOT rules (Bernardin &
Stiefelhagen, 2008): a correspondence made in one frame is kept while the pair stays within
``match_m``; the rest are matched by the Hungarian method on distance (``match_m`` gate).
Only people the lidar can see count as ground truth: within ``max_range_m`` of the sensor and
hit by at least ``min_beams`` returns of the scan. A track matched to a person who does not
count (hidden, too far) is neither a hit nor a false positive.

* ``mota`` = 1 − (misses + false positives + identity switches) / ground-truth objects;
* ``motp_m`` = mean distance of the matched pairs, metres;
* ``velocity_rmse_mps`` = RMS error of the matched tracks' velocities, m/s.

:class:`Proximity` measures, from ground truth, the distance between the rover's footprint
and each person's body (edge to edge; negative: overlap): the minimum, the time any person is
nearer than ``near_m`` (0.3 m) and *encounters* — a person coming within ``enter_m`` (1 m)
until they are again farther than ``exit_m`` (1.5 m) — with each encounter's minimum, the
minimum while the rover moved, and whether the rover was closing in on the person (its own
motion shrinking the distance by more than 0.05 m/s,
:data:`curio.safety.stop_zone.ROVER_CLOSING_MPS`, as for the simulator's collision fault)
when they were nearest: an encounter
below ``near_m`` in which the rover was not is one the person made (walking past or into a
rover that stood still, turned away or drove away).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from curio.core.geometry import Pose2D
from curio.core.messages import PeopleTracks, SimPeople
from curio.safety.stop_zone import ROVER_CLOSING_MPS, closing_speeds_mps, polygon_distances

__all__ = ["MotAccumulator", "Proximity"]

F64 = npt.NDArray[np.float64]


@dataclass
class MotAccumulator:
    """CLEAR MOT counts over many frames (see the module docstring)."""

    match_m: float = 0.5
    max_range_m: float = 8.0
    min_beams: int = 3
    frames: int = 0
    objects: int = 0
    misses: int = 0
    false_positives: int = 0
    switches: int = 0
    matches: int = 0
    distance_sum_m: float = 0.0
    velocity_sq_sum: float = 0.0
    _last: dict[int, int] = field(default_factory=dict)  # person id -> track id

    def add(self, truth: SimPeople, tracks: PeopleTracks, sensor: tuple[float, float]) -> None:
        """Score one frame: ``truth`` and ``tracks`` at (nearly) the same stamp; ``sensor`` is
        the lidar's position (map)."""
        self.frames += 1
        dt = tracks.stamp - truth.stamp
        people = [(p.person_id, p.x_m + p.vx_mps * dt, p.y_m + p.vy_mps * dt, p)
                  for p in truth.people]
        counted = {pid for pid, x, y, p in people
                   if p.visible_beams >= self.min_beams
                   and math.hypot(x - sensor[0], y - sensor[1]) <= self.max_range_m}
        self.objects += len(counted)
        pos = {pid: (x, y, p) for pid, x, y, p in people}
        tr = {t.track_id: t for t in tracks.tracks}
        pairs: dict[int, int] = {}
        for pid, tid in self._last.items():  # keep last frame's correspondences
            if pid in pos and tid in tr and self._dist(pos[pid], tr[tid]) <= self.match_m:
                pairs[pid] = tid
        free_p = [pid for pid in pos if pid not in pairs]
        used = set(pairs.values())
        free_t = [tid for tid in tr if tid not in used]
        if free_p and free_t:
            cost = np.array([[self._dist(pos[p], tr[t]) for t in free_t] for p in free_p])
            rows, cols = linear_sum_assignment(np.where(cost <= self.match_m, cost, 1e6))
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= self.match_m:
                    pairs[free_p[r]] = free_t[c]
        for pid, tid in pairs.items():
            if pid not in counted:
                continue  # matched to someone the lidar cannot see: neither hit nor error
            self.matches += 1
            x, y, p = pos[pid]
            t = tr[tid]
            self.distance_sum_m += math.hypot(t.x_m - x, t.y_m - y)
            self.velocity_sq_sum += (t.vx_mps - p.vx_mps) ** 2 + (t.vy_mps - p.vy_mps) ** 2
            if pid in self._last and self._last[pid] != tid:
                self.switches += 1
        self.misses += len(counted - {pid for pid in pairs if pid in counted})
        matched_t = set(pairs.values())
        self.false_positives += sum(1 for tid in tr if tid not in matched_t)
        self._last.update(pairs)

    @staticmethod
    def _dist(p: tuple[float, float, Any], t: Any) -> float:
        return math.hypot(float(t.x_m) - p[0], float(t.y_m) - p[1])

    @property
    def mota(self) -> float | None:
        """1 − (misses + false positives + switches) / objects (None before any object)."""
        if self.objects == 0:
            return None
        return 1.0 - (self.misses + self.false_positives + self.switches) / self.objects

    @property
    def motp_m(self) -> float | None:
        """Mean distance of the matched pairs, metres."""
        return self.distance_sum_m / self.matches if self.matches else None

    @property
    def velocity_rmse_mps(self) -> float | None:
        """RMS velocity error of the matched tracks, m/s."""
        return math.sqrt(self.velocity_sq_sum / self.matches) if self.matches else None

    def summary(self) -> dict[str, Any]:
        """The figures and counts."""
        return {"tracks_mota": self.mota, "tracks_motp_m": self.motp_m,
                "tracks_velocity_rmse_mps": self.velocity_rmse_mps,
                "tracks_objects": self.objects, "tracks_misses": self.misses,
                "tracks_false_positives": self.false_positives,
                "tracks_id_switches": self.switches, "tracks_frames": self.frames}


@dataclass
class _Encounter:
    start_s: float
    min_m: float
    moving_min_m: float = math.inf
    rover_closing: bool = False  # the rover's motion closed in on them at the minimum


@dataclass
class Proximity:
    """Footprint-to-body distances to people (see the module docstring).

    Args:
        footprint: the rover's footprint polygon in ``base_link`` (``(E, 2)``, metres).
    """

    footprint: F64
    near_m: float = 0.3
    enter_m: float = 1.0
    exit_m: float = 1.5
    min_distance_m: float = math.inf
    min_moving_m: float = math.inf
    time_below_s: float = 0.0
    encounters: list[_Encounter] = field(default_factory=list)
    _open: dict[int, _Encounter] = field(default_factory=dict)
    _last_t: float | None = None

    def add(self, t: float, rover: Pose2D, rover_speed_mps: float, ids: list[int], xy: F64,
            radii: F64, rover_yaw_rate_radps: float = 0.0) -> None:
        """One sample at clock ``t``: the rover's true pose and body twist (m/s, rad/s), and
        each person's id, position ``(N, 2)`` (map, m) and body radius (m)."""
        dt = 0.0 if self._last_t is None else max(0.0, t - self._last_t)
        self._last_t = t
        if not ids:
            return
        d = polygon_distances(rover.inverse().transform_points(xy), self.footprint) - radii
        closing = np.zeros(len(d), dtype=bool)
        close = d < self.enter_m
        if close.any():
            closing[close] = closing_speeds_mps(self.footprint, rover, rover_speed_mps,
                                                rover_yaw_rate_radps, xy[close]) \
                > ROVER_CLOSING_MPS
        moving = abs(rover_speed_mps) > 0.02
        nearest = float(d.min())
        self.min_distance_m = min(self.min_distance_m, nearest)
        if moving:
            self.min_moving_m = min(self.min_moving_m, nearest)
        if nearest < self.near_m:
            self.time_below_s += dt
        for pid, di, ci in zip(ids, d.tolist(), closing.tolist(), strict=True):
            enc = self._open.get(pid)
            if enc is None and di < self.enter_m:
                enc = self._open[pid] = _Encounter(t, di)
                self.encounters.append(enc)
            if enc is not None:
                if di <= enc.min_m:
                    enc.min_m, enc.rover_closing = di, bool(ci)
                if moving:
                    enc.moving_min_m = min(enc.moving_min_m, di)
                if di > self.exit_m:
                    del self._open[pid]

    def summary(self) -> dict[str, Any]:
        """The figures: minimum distance, time below ``near_m``, encounters."""
        n = len(self.encounters)
        ok = sum(1 for e in self.encounters if e.min_m >= self.near_m)
        ok_moving = sum(1 for e in self.encounters if e.moving_min_m >= self.near_m)
        by_person = sum(1 for e in self.encounters
                        if e.min_m < self.near_m and not e.rover_closing)
        return {
            "min_person_distance_m": None if math.isinf(self.min_distance_m)
            else self.min_distance_m,
            "min_person_distance_moving_m": None if math.isinf(self.min_moving_m)
            else self.min_moving_m,
            "time_below_0_3m_s": self.time_below_s,
            "encounters": n,
            "encounters_ok": ok,
            "encounters_ok_fraction": ok / n if n else None,
            "encounters_ok_moving_fraction": ok_moving / n if n else None,
            "encounters_below_by_person": by_person,
            "encounters_ok_or_by_person_fraction": (ok + by_person) / n if n else None,
        }
