"""Other rovers as moving obstacles with known intent, for the people-aware controller.

A person's future is guessed (constant velocity from the tracker); another rover *says* where
it is going: every traffic message (``curio/<rover>/traffic``, 5 Hz while it has a goal)
carries its pose, speed and the next 8 m of its plan. :class:`RoverIntent` turns the fresh
peers of the traffic part's :class:`~curio.fleet.traffic.PeerTable` into what the people stage
(:attr:`curio.people.stage.PeopleStage.movers`) predicts with: each rover's position now, its
velocity along its plan, a circle round its footprint, and its predicted position at every
step of the stage's horizon — along its plan at its present speed, not on a straight line.

* The prediction starts where the rover was when it sent the message, advanced by the
  message's age (the sender's wall clock against ours, at most ``MAX_AGE_S``).
* A rover that gives way at a passage says how far it drives on before it holds
  (``stop_in``): its prediction ends there, short of the passage.
* A rover that is holding for another one (right of way ``yield`` and standing), or has no
  goal, or is slower than ``STILL_MPS``, stays where it is over the horizon, and counts as an
  obstacle that does not walk (the stage then keeps only its minimum distance, not a
  walker's comfortable one): a rover waiting at a staging point is passed like a pillar.
* Peers not heard within ``fleet.traffic.peer_timeout_s`` are left to the lidar.
* A rover that gives way *to this one* at a passage is left out: the right-of-way rule has
  settled that encounter (it holds at its staging point, this one goes), and predicting it
  there only made the rover that has the passage linger beside it (``curio bench fleet``
  seed 25 deadlocked that way).

The right-of-way rule (:mod:`curio.fleet.traffic`) stays above the controller as it was: it
decides who goes first through a narrow passage; this only makes the controller see where the
other rover will be in the next seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from curio.fleet.traffic import PeerTable, PeerTrack

__all__ = ["KnownMovers", "RoverIntent", "known_rovers", "predict_along"]

F64 = npt.NDArray[np.float64]

STILL_MPS = 0.03
MAX_AGE_S = 1.0
HEADING_STEP_M = 0.05


@dataclass(frozen=True)
class KnownMovers:
    """Obstacles whose future is known, for a horizon of ``K`` steps.

    Attributes:
        now: ``(J, 5)`` x, y (``map``, m), vx, vy (m/s) now, and 1 for one that moves (0: it
            stands: ask only the minimum distance).
        future: ``(J, K, 2)`` predicted x, y (``map``, m) at each of the horizon's times.
        radius_m: ``(J,)`` a circle round each one's footprint, m.
        names: ``rover:<name>`` of each.
    """

    now: F64
    future: F64
    radius_m: F64
    names: tuple[str, ...]

    @classmethod
    def empty(cls, k: int) -> KnownMovers:
        """No movers."""
        return cls(np.zeros((0, 5)), np.zeros((0, k, 2)), np.zeros(0), ())


def predict_along(start: tuple[float, float], path: F64, speed_mps: float, times: F64,
                  stop_after_m: float | None = None) -> F64:
    """``(K, 2)`` positions (m) at ``times`` (s from now) of a body at ``start`` driving along
    ``path`` (``(N, 2)``, the points ahead) at ``speed_mps``; it stops at the path's end, or
    after ``stop_after_m`` metres when given."""
    pts = np.vstack([np.asarray(start, dtype=np.float64).reshape(1, 2),
                     np.asarray(path, dtype=np.float64).reshape(-1, 2)])
    seg = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    end = s[-1] if stop_after_m is None else min(s[-1], max(stop_after_m, 0.0))
    want = np.clip(max(speed_mps, 0.0) * np.asarray(times, dtype=np.float64), 0.0, end)
    if s[-1] <= 0.0:
        return np.repeat(pts[:1], len(want), axis=0)
    return np.column_stack([np.interp(want, s, pts[:, 0]), np.interp(want, s, pts[:, 1])])


def _heading_along(start: tuple[float, float], path: F64, along_m: float,
                   yaw: float) -> tuple[float, float]:
    """A unit vector along ``path`` where a body that started at ``start`` is after
    ``along_m`` metres (the body's yaw where the path gives none)."""
    ends = predict_along(start, path, 1.0, np.array([along_m, along_m + HEADING_STEP_M]))
    d = ends[1] - ends[0]
    norm = float(np.hypot(d[0], d[1]))
    if norm < 1e-6:
        return math.cos(yaw), math.sin(yaw)
    return float(d[0] / norm), float(d[1] / norm)


def known_rovers(peers: PeerTable, wall_time: Callable[[], float],
                 timeout_s: float) -> Callable[[], F64]:
    """For :attr:`curio.people.stage.PeopleStage.rovers`: every peer heard from within
    ``timeout_s`` (whatever it is doing, holding included) as ``(J, 3)`` x, y (``map``, m)
    and the radius round its footprint (m), so the people stage does not take it for a
    person."""

    def now() -> F64:
        fresh = peers.fresh(wall_time(), timeout_s)
        return np.array([(p.pose.x, p.pose.y, p.radius_m) for p in fresh],
                        dtype=np.float64).reshape(-1, 3)

    return now


class RoverIntent:
    """The other rovers as :class:`KnownMovers` (see the module docstring).

    Args:
        peers: the traffic part's table of the other rovers' latest messages.
        wall_time: our wall clock, seconds (message ages are measured on it).
        timeout_s: peers older than this are ignored (``fleet.traffic.peer_timeout_s``).
    """

    def __init__(self, peers: PeerTable, wall_time: Callable[[], float],
                 timeout_s: float) -> None:
        self.peers = peers
        self.wall_time = wall_time
        self.timeout_s = timeout_s
        self.calls = 0

    def __call__(self, times: F64) -> KnownMovers:
        """The fresh peers, predicted at ``times`` (s from now)."""
        self.calls += 1
        now = self.wall_time()
        fresh = self.peers.fresh(now, self.timeout_s)
        rows, futures, radii, names = [], [], [], []
        for p in fresh:
            if p.state == "yield" and p.yield_to == self.peers.me:
                continue  # the rule has settled it: it holds for us
            age = min(max(now - p.wall_s, 0.0), MAX_AGE_S)
            moving = self._moving(p)
            speed = abs(p.speed_mps) if moving else 0.0
            future = predict_along((p.pose.x, p.pose.y), p.plan, speed,
                                   np.asarray(times, dtype=np.float64) + age, p.stop_in_m)
            ux, uy = _heading_along((p.pose.x, p.pose.y), p.plan, speed * age, p.pose.yaw)
            rows.append((future[0, 0], future[0, 1], speed * ux, speed * uy,
                         1.0 if moving else 0.0))
            futures.append(future)
            radii.append(p.radius_m)
            names.append(f"rover:{p.name}")
        if not rows:
            return KnownMovers.empty(len(times))
        return KnownMovers(np.array(rows, dtype=np.float64), np.stack(futures),
                           np.array(radii, dtype=np.float64), tuple(names))

    @staticmethod
    def _moving(p: PeerTrack) -> bool:
        """Whether it drives on over the horizon (not holding, with a goal, not standing)."""
        holding = p.state == "yield" and abs(p.speed_mps) < 0.05
        return p.goal and not holding and abs(p.speed_mps) >= STILL_MPS
