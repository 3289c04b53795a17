"""Multi-person tracking: a constant-velocity Kalman filter per person, Hungarian association.

Each scan's detections (:mod:`curio.people.detect`, ``map`` metres) update the tracks:

1. **Predict** every track to the scan's stamp with its own filterpy ``KalmanFilter`` (state
   x, y, vx, vy; constant velocity; white-acceleration process noise of
   ``accel_sigma_mps2`` from ``Q_discrete_white_noise``; measurement noise
   ``measurement_sigma_m``).
2. **Associate** detections with tracks by ``scipy.optimize.linear_sum_assignment`` on their
   distances; a pair farther apart than ``gate_m`` is not a match.
3. **Update** matched tracks; every unmatched detection starts a *tentative* track (velocity
   unknown: 1 m/s standard deviation).
4. **Birth and death** — a track is *confirmed* (published) after ``confirm_hits``
   detections; an unconfirmed one without a detection for ``tentative_coast_s`` is dropped,
   a confirmed one after ``coast_s`` (it coasts on its prediction meanwhile, e.g. behind
   another person) — but after ``tentative_coast_s`` only when the scan saw *through* the
   place it predicts (negative information: the person is not there, not hidden) — as is
   one that coasts into a mapped wall, or duplicates an older track (two tracks on one
   person). Ids are never reused.

A track has *walked* once it has moved 0.8 m from where it was born or been faster than
``moving_speed_mps`` on three updates in a row: pillars and bins rarely walk, so the
controller can tell people from furniture the map does not show. (A box seen from a moving
rover can pass for walking: its velocity estimate jitters. Requiring 0.3 m of travel too was
tried at the merge; it cost two rover-rover doorway runs in 50 and was undone — the people
stage's assertive phase handles the boxes instead.) A track has *travelled* once it moved
0.8 m from its birth place: what the localiser leaves out of its fit (a box never travels).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.optimize import linear_sum_assignment

from curio.core.config import PeopleConfig
from curio.core.messages import PersonTrack
from curio.people.detect import Detection, StaticMap

__all__ = ["Track", "Tracker"]

F64 = npt.NDArray[np.float64]
WALKED_M = 0.8
DUPLICATE_M = 0.25
TRAIL_S = 3.0
MAX_STD_M = 1.0


@dataclass
class Track:
    """One person's track (see the module docstring)."""

    track_id: int
    kf: KalmanFilter
    born_s: float
    birth_xy: tuple[float, float]
    stamp_s: float
    last_seen_s: float
    hits: int = 1
    confirmed: bool = False
    walked: bool = False
    travelled: bool = False  # moved WALKED_M from its birth place (velocity jitter never does)
    fast_updates: int = 0
    std_m: float = 0.0  # pos_std_m at the last update
    still_since_s: float | None = None
    beams: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    trail: deque[tuple[float, float, float]] = field(default_factory=lambda: deque(maxlen=64))

    @property
    def xy(self) -> tuple[float, float]:
        """Estimated position (map, m)."""
        return float(self.kf.x[0, 0]), float(self.kf.x[1, 0])

    @property
    def velocity(self) -> tuple[float, float]:
        """Estimated velocity (map, m/s)."""
        return float(self.kf.x[2, 0]), float(self.kf.x[3, 0])

    @property
    def speed_mps(self) -> float:
        """Estimated speed, m/s."""
        vx, vy = self.velocity
        return math.hypot(vx, vy)

    @property
    def pos_std_m(self) -> float:
        """Standard deviation of the position along its worse axis, m."""
        p = self.kf.P[:2, :2]
        tr, det = p[0, 0] + p[1, 1], p[0, 0] * p[1, 1] - p[0, 1] * p[1, 0]
        return math.sqrt(max(0.5 * tr + math.sqrt(max(0.25 * tr * tr - det, 0.0)), 0.0))


class Tracker:
    """Keeps the people tracks (see the module docstring).

    Args:
        cfg: ``people``.
        static: the static map's distance field (tracks that coast into walls are dropped).
    """

    def __init__(self, cfg: PeopleConfig, static: StaticMap | None = None) -> None:
        self.cfg = cfg
        self.static = static
        self.tracks: list[Track] = []
        self._next_id = 1
        self._models: dict[float, tuple[F64, F64]] = {}
        self.births = 0
        self.deaths = 0

    # -- the filter model --------------------------------------------------------------------
    def _model(self, dt: float) -> tuple[F64, F64]:
        """``F`` and ``Q`` of the constant-velocity model for a step of ``dt`` seconds."""
        key = round(dt, 4)
        model = self._models.get(key)
        if model is None:
            f = np.eye(4)
            f[0, 2] = f[1, 3] = key
            q = Q_discrete_white_noise(2, dt=key, var=self.cfg.accel_sigma_mps2 ** 2,
                                       block_size=2, order_by_dim=False)
            model = (f, q)
            if len(self._models) < 256:
                self._models[key] = model
        return model

    def _new_track(self, det: Detection, stamp: float) -> Track:
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([[det.x_m], [det.y_m], [0.0], [0.0]])
        sig = self.cfg.measurement_sigma_m
        kf.P = np.diag([sig * sig, sig * sig, 1.0, 1.0])
        kf.H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
        kf.R = np.eye(2) * sig * sig
        track = Track(self._next_id, kf, stamp, (det.x_m, det.y_m), stamp, stamp,
                      beams=det.beams)
        track.confirmed = self.cfg.confirm_hits <= 1
        self._next_id += 1
        self.births += 1
        return track

    # -- one scan ----------------------------------------------------------------------------
    def update(self, detections: list[Detection], stamp: float,
               seen_through: Callable[[float, float], bool] | None = None) -> list[Track]:
        """Predict, associate, update, give birth and drop; return the confirmed tracks.

        ``seen_through(x, y)`` tells whether the scan saw past map point (x, y) (None: the
        scan is not known; every miss counts as a hidden person).
        """
        for t in self.tracks:
            dt = stamp - t.stamp_s
            if dt > 0.0:
                t.kf.F, t.kf.Q = self._model(dt)
                t.kf.predict()
                t.stamp_s = stamp
            t.beams = np.zeros(0, dtype=np.int64)
        matched = self._associate(detections)
        for ti, di in matched:
            self._correct(self.tracks[ti], detections[di], stamp)
        taken = {di for _, di in matched}
        for di, det in enumerate(detections):
            if di not in taken:
                self.tracks.append(self._new_track(det, stamp))
        self._prune(stamp, seen_through)
        return [t for t in self.tracks if t.confirmed]

    def _associate(self, detections: list[Detection]) -> list[tuple[int, int]]:
        if not self.tracks or not detections:
            return []
        tx = np.array([t.xy for t in self.tracks])
        dx = np.array([(d.x_m, d.y_m) for d in detections])
        cost = np.hypot(tx[:, None, 0] - dx[None, :, 0], tx[:, None, 1] - dx[None, :, 1])
        # Confirmed tracks win a tie against tentative ones.
        cost += np.array([0.0 if t.confirmed else 0.05 for t in self.tracks])[:, None]
        gate = self.cfg.gate_m
        rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, 1e6))
        return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] <= gate]

    def _correct(self, t: Track, det: Detection, stamp: float) -> None:
        t.kf.update(np.array([[det.x_m], [det.y_m]]))
        t.hits += 1
        t.last_seen_s = stamp
        t.beams = det.beams
        if t.hits >= self.cfg.confirm_hits:
            t.confirmed = True
        speed = t.speed_mps
        t.fast_updates = t.fast_updates + 1 if speed > self.cfg.moving_speed_mps else 0
        x, y = t.xy
        if not t.travelled and math.hypot(x - t.birth_xy[0], y - t.birth_xy[1]) > WALKED_M:
            t.travelled = True
        if not t.walked and (t.fast_updates >= 3 or t.travelled):
            t.walked = True
        if speed > self.cfg.moving_speed_mps:
            t.still_since_s = None
        elif t.still_since_s is None:
            t.still_since_s = stamp
        if not t.trail or math.hypot(x - t.trail[-1][0], y - t.trail[-1][1]) > 0.1:
            t.trail.append((x, y, stamp))
        while t.trail and stamp - t.trail[0][2] > TRAIL_S:
            t.trail.popleft()

    def _prune(self, stamp: float, seen_through: Callable[[float, float], bool] | None) -> None:
        keep: list[Track] = []
        cfg = self.cfg
        xy = np.array([t.xy for t in self.tracks]) if self.tracks else np.zeros((0, 2))
        wall = self.static.distance_at(xy) if self.static is not None and len(xy) else None
        for k, t in enumerate(self.tracks):
            t.std_m = t.pos_std_m
            missed = stamp - t.last_seen_s
            hidden = missed <= 0.0 or seen_through is None or not seen_through(*t.xy)
            coast = cfg.coast_s if t.confirmed and hidden else cfg.tentative_coast_s
            in_wall = wall is not None and missed > 0.0 and 0.0 <= wall[k] < 0.05
            if missed > coast or t.std_m > MAX_STD_M or in_wall:
                self.deaths += 1
                continue
            keep.append(t)
        # Two tracks on one person: the younger goes.
        out: list[Track] = []
        for t in sorted(keep, key=lambda t: t.born_s):
            x, y = t.xy
            if any(math.hypot(x - o.xy[0], y - o.xy[1]) < DUPLICATE_M for o in out):
                self.deaths += 1
                continue
            out.append(t)
        self.tracks = sorted(out, key=lambda t: t.track_id)

    # -- output ------------------------------------------------------------------------------
    def message_tracks(self, stamp: float) -> tuple[PersonTrack, ...]:
        """The confirmed tracks as messages."""
        out = []
        for t in self.tracks:
            if not t.confirmed:
                continue
            x, y = t.xy
            vx, vy = t.velocity
            standing = (stamp - t.still_since_s
                        if t.walked and t.still_since_s is not None else 0.0)
            out.append(PersonTrack(t.track_id, x, y, vx, vy, t.std_m, stamp - t.born_s,
                                   t.speed_mps > self.cfg.moving_speed_mps, t.walked, standing,
                                   stamp - t.last_seen_s))
        return tuple(out)
