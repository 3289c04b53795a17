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

The filter is filterpy's ``KalmanFilter`` (each track keeps one), its predict and update done
by :func:`_predict` and :func:`_update` with filterpy's operations and products — the same
bits — without its per-call overhead (copies of the prior and posterior, a deep copy of each
measurement, checks, a general 2 × 2 inverse): the filters' ``x`` and ``P`` are kept, the rest
of filterpy's bookkeeping (``x_prior``, ``K``, ``S``, …) is not.

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
from curio.people.tracking_kernel import kalman_correct

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
        x = self.kf.x
        return x.item(0), x.item(1)

    @property
    def velocity(self) -> tuple[float, float]:
        """Estimated velocity (map, m/s)."""
        x = self.kf.x
        return x.item(2), x.item(3)

    @property
    def speed_mps(self) -> float:
        """Estimated speed, m/s."""
        vx, vy = self.velocity
        return math.hypot(vx, vy)

    @property
    def pos_std_m(self) -> float:
        """Standard deviation of the position along its worse axis, m."""
        p = self.kf.P
        p00, p01, p10, p11 = p.item(0, 0), p.item(0, 1), p.item(1, 0), p.item(1, 1)
        tr, det = p00 + p11, p00 * p11 - p01 * p10
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
        none = np.zeros(0, dtype=np.int64)
        for t in self.tracks:
            dt = stamp - t.stamp_s
            if dt > 0.0:
                _predict(t.kf, *self._model(dt))
                t.stamp_s = stamp
            t.beams = none  # never written to: one empty array serves every track
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
        near = (cost[rows, cols] <= gate).tolist()
        return [(r, c) for r, c, ok in zip(rows.tolist(), cols.tolist(), near, strict=True)
                if ok]

    def _correct(self, t: Track, det: Detection, stamp: float) -> None:
        _update(t.kf, det.x_m, det.y_m)
        t.hits += 1
        t.last_seen_s = stamp
        t.beams = det.beams
        if t.hits >= self.cfg.confirm_hits:
            t.confirmed = True
        x, y, vx, vy = t.kf.x[:, 0].tolist()
        speed = math.hypot(vx, vy)
        t.fast_updates = t.fast_updates + 1 if speed > self.cfg.moving_speed_mps else 0
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
        keep: list[tuple[Track, tuple[float, float]]] = []
        cfg = self.cfg
        xys = [t.xy for t in self.tracks]
        wall = (self.static.distance_at(np.array(xys)).tolist()
                if self.static is not None and xys else None)
        for k, t in enumerate(self.tracks):
            t.std_m = t.pos_std_m
            missed = stamp - t.last_seen_s
            hidden = missed <= 0.0 or seen_through is None or not seen_through(*xys[k])
            coast = cfg.coast_s if t.confirmed and hidden else cfg.tentative_coast_s
            in_wall = wall is not None and missed > 0.0 and 0.0 <= wall[k] < 0.05
            if missed > coast or t.std_m > MAX_STD_M or in_wall:
                self.deaths += 1
                continue
            keep.append((t, xys[k]))
        # Two tracks on one person: the younger goes.
        out: list[Track] = []
        out_xy: list[tuple[float, float]] = []
        for t, (x, y) in sorted(keep, key=lambda kept: kept[0].born_s):
            if any(math.hypot(x - ox, y - oy) < DUPLICATE_M for ox, oy in out_xy):
                self.deaths += 1
                continue
            out.append(t)
            out_xy.append((x, y))
        self.tracks = sorted(out, key=lambda t: t.track_id)

    # -- output ------------------------------------------------------------------------------
    def message_tracks(self, stamp: float) -> tuple[PersonTrack, ...]:
        """The confirmed tracks as messages."""
        out = []
        for t in self.tracks:
            if not t.confirmed:
                continue
            x, y, vx, vy = t.kf.x[:, 0].tolist()
            standing = (stamp - t.still_since_s
                        if t.walked and t.still_since_s is not None else 0.0)
            out.append(PersonTrack(t.track_id, x, y, vx, vy, t.std_m, stamp - t.born_s,
                                   math.hypot(vx, vy) > self.cfg.moving_speed_mps, t.walked,
                                   standing, stamp - t.last_seen_s))
        return tuple(out)


def _predict(kf: KalmanFilter, f: F64, q: F64) -> None:
    """filterpy's ``kf.predict()`` with transition ``f`` and process noise ``q``: ``x = F x``,
    ``P = F P Fᵀ + Q`` — its numpy products in its order; its fading-memory factor α² is 1
    here (a product by 1.0 changes no bit) and there is no control input."""
    kf.F, kf.Q = f, q
    if kf._alpha_sq != 1.0 or kf.B is not None:
        kf.predict()  # not the tracker's filter: filterpy's own
        return
    kf.x = np.dot(f, kf.x)
    kf.P = np.dot(np.dot(f, kf.P), f.T) + q


def _update(kf: KalmanFilter, x_m: float, y_m: float) -> None:
    """filterpy's ``kf.update([[x_m], [y_m]])``: the compiled
    :func:`~curio.people.tracking_kernel.kalman_correct` (the products whose elements have one
    non-zero term), then the Joseph form's ``(I − KH) P (I − KH)ᵀ`` as filterpy computes it.
    A filter without the tracker's structure gets filterpy's own update."""
    ok, x, i_kh, krk = kalman_correct(kf.x, kf.P, kf.H, kf.R, float(x_m), float(y_m))
    if not ok:
        kf.update(np.array([[x_m], [y_m]]))
        return
    kf.P = np.dot(np.dot(i_kh, kf.P), i_kh.T) + krk
    kf.x = x
