"""Scoring a SLAM trajectory with ground-truth relative relations (the Freiburg SLAM benchmark).

The metric is the one of R. Kümmerle, B. Steder, C. Dornhege, M. Ruhnke, G. Grisetti,
C. Stachniss and A. Kleiner, *On measuring the accuracy of SLAM algorithms*, Autonomous Robots
27(4):387–407, 2009 (the "Freiburg benchmark"; its relation files ship with the public logs:
MIT CSAIL, Intel lab, ACES, Freiburg 079 ...). It uses only relative displacements between
poses, never a global frame, so a trajectory need not be aligned with anything to be scored.

**Relations file** (text, one relation a line, whitespace-separated, ``#`` starts a comment)::

    t1 t2 x y z roll pitch yaw

``t1``, ``t2``: timestamps (seconds, the log's laser timestamps); ``x y z``: the true position
of the robot at ``t2`` in the robot frame at ``t1`` (metres); ``roll pitch yaw``: the true
rotation (radians). For planar logs ``z``, ``roll`` and ``pitch`` are 0 and ignored.

**Trajectory** (CSV, as ``curio map build --trajectory`` writes it): an optional header
``t,x,y,yaw`` and one pose a line — seconds, metres, metres, radians — of ``base_link`` in
``map``.

**Matching timestamps.** The benchmark's relations name laser timestamps of the log, and a
SLAM system reports one pose per laser scan, so every relation time is matched to the
trajectory pose with the *nearest* timestamp; a match further than ``max_dt_s`` (default 1 ms —
the relation files are written to 10 µs) does not count and the relation is reported as
unmatched, never silently scored against a pose of another scan.

**Error of one relation** (the paper's ε with δ ⊖ δ*): with the estimated poses
``x1 = (p1, θ1)`` and ``x2 = (p2, θ2)`` the estimated relative motion is
``δ = x1⁻¹ ⊕ x2`` — translation ``R(θ1)ᵀ (p2 − p1)``, rotation ``θ2 − θ1`` — and the relation
is ``δ* = (x, y, yaw)``. The error transform ``δ*⁻¹ ⊕ δ`` has the translation norm
``|t(δ) − t(δ*)|`` (a rotation does not change a norm) and the rotation
``|wrap(θ(δ) − yaw)|``. Reported: the mean ± standard deviation (population, as the paper's
tables) of the absolute translational error (metres) and rotational error (degrees), the
maximum of each with the relation it comes from, and how many relations were matched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

__all__ = [
    "Relation",
    "RelationError",
    "Score",
    "read_relations",
    "read_trajectory",
    "score_trajectory",
]

F64 = npt.NDArray[np.float64]


class RelationError(ValueError):
    """A relations file or trajectory that cannot be read: the file, the line and the problem."""


@dataclass(frozen=True, slots=True)
class Relation:
    """One ground-truth relation: the pose at ``t2_s`` in the robot frame at ``t1_s``.

    Attributes:
        t1_s, t2_s: timestamps, seconds.
        x_m, y_m: translation in the frame of the pose at ``t1_s``, metres.
        yaw_rad: rotation, radians.
    """

    t1_s: float
    t2_s: float
    x_m: float
    y_m: float
    yaw_rad: float


@dataclass(frozen=True, slots=True)
class Score:
    """The relative-relation error of a trajectory.

    Attributes:
        relations: relations in the file.
        matched: relations whose two timestamps both matched a trajectory pose.
        trans_mean_m, trans_std_m, trans_max_m: absolute translational error, metres.
        rot_mean_deg, rot_std_deg, rot_max_deg: absolute rotational error, degrees.
        worst_trans: the relation with the largest translational error (None if none matched).
        worst_rot: the relation with the largest rotational error.
        trans_errors_m, rot_errors_deg: per matched relation, in file order.
    """

    relations: int
    matched: int
    trans_mean_m: float
    trans_std_m: float
    trans_max_m: float
    rot_mean_deg: float
    rot_std_deg: float
    rot_max_deg: float
    worst_trans: Relation | None
    worst_rot: Relation | None
    trans_errors_m: F64
    rot_errors_deg: F64

    def as_dict(self) -> dict[str, float | int]:
        """The figures as a flat dict with units in the names (for benchmarks and JSON)."""
        return {
            "relations": self.relations,
            "matched": self.matched,
            "trans_mean_m": self.trans_mean_m,
            "trans_std_m": self.trans_std_m,
            "trans_max_m": self.trans_max_m,
            "rot_mean_deg": self.rot_mean_deg,
            "rot_std_deg": self.rot_std_deg,
            "rot_max_deg": self.rot_max_deg,
        }


def _numbers(path: Path, lineno: int, fields: list[str], what: str) -> list[float]:
    out: list[float] = []
    for i, f in enumerate(fields, start=1):
        try:
            v = float(f)
        except ValueError:
            raise RelationError(f"{path}:{lineno}: {what}: field {i} is {f!r}, not a number") \
                from None
        if not math.isfinite(v):
            raise RelationError(f"{path}:{lineno}: {what}: field {i} is {f!r}, not finite")
        out.append(v)
    return out


def _lines(path: Path, what: str) -> list[str]:
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise RelationError(f"{path}: no such {what} file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RelationError(f"{path}: cannot read the {what} file ({exc})") from None


def read_relations(path: Path | str) -> list[Relation]:
    """Read a Freiburg relations file (see the module docstring).

    Raises:
        RelationError: a missing or unreadable file, a line without 8 numbers, no relation.
    """
    p = Path(path)
    rels: list[Relation] = []
    for lineno, line in enumerate(_lines(p, "relations"), start=1):
        body = line.split("#", 1)[0].split()
        if not body:
            continue
        if len(body) != 8:
            raise RelationError(f"{p}:{lineno}: a relation has 8 fields (t1 t2 x y z roll pitch "
                                f"yaw), got {len(body)}")
        t1, t2, x, y, _z, _roll, _pitch, yaw = _numbers(p, lineno, body, "relation")
        rels.append(Relation(t1, t2, x, y, yaw))
    if not rels:
        raise RelationError(f"{p}: no relations (expected lines 't1 t2 x y z roll pitch yaw')")
    return rels


def read_trajectory(path: Path | str) -> F64:
    """Read a trajectory CSV (``t,x,y,yaw``) as an ``(N, 4)`` array sorted by time.

    Raises:
        RelationError: a missing or unreadable file, a line without 4 numbers, no pose.
    """
    p = Path(path)
    rows: list[list[float]] = []
    for lineno, line in enumerate(_lines(p, "trajectory"), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f.strip() for f in s.split(",")]
        if lineno == 1 and fields and fields[0].lower() in ("t", "time", "stamp", "t_s"):
            if [f.lower() for f in fields] != ["t", "x", "y", "yaw"]:
                raise RelationError(f"{p}:1: the header must be 't,x,y,yaw', got {s!r}")
            continue
        if len(fields) != 4:
            raise RelationError(f"{p}:{lineno}: a pose has 4 comma-separated fields "
                                f"(t,x,y,yaw: s, m, m, rad), got {len(fields)}")
        rows.append(_numbers(p, lineno, fields, "pose"))
    if not rows:
        raise RelationError(f"{p}: no poses (expected lines 't,x,y,yaw')")
    traj = np.asarray(rows, dtype=np.float64)
    return traj[np.argsort(traj[:, 0], kind="stable")]


def _nearest(times: F64, t: F64) -> tuple[npt.NDArray[np.int64], F64]:
    """Index of the nearest time in sorted ``times`` for each of ``t``, and the gap (s)."""
    i = np.clip(np.searchsorted(times, t), 1, max(1, len(times) - 1))
    lo = np.clip(i - 1, 0, len(times) - 1)
    hi = np.clip(i, 0, len(times) - 1)
    pick = np.where(np.abs(times[lo] - t) <= np.abs(times[hi] - t), lo, hi)
    return pick.astype(np.int64), np.abs(times[pick] - t)


def score_trajectory(traj: F64, relations: list[Relation], max_dt_s: float = 1e-3) -> Score:
    """The relative-relation error of ``traj`` (``(N, 4)``: t s, x m, y m, yaw rad in ``map``).

    Args:
        traj: poses sorted by time.
        relations: the ground truth.
        max_dt_s: the largest gap between a relation's timestamp and the matched pose, seconds.
    """
    rel = np.array([(r.t1_s, r.t2_s, r.x_m, r.y_m, r.yaw_rad) for r in relations],
                   dtype=np.float64).reshape(-1, 5)
    i1, g1 = _nearest(traj[:, 0], rel[:, 0])
    i2, g2 = _nearest(traj[:, 0], rel[:, 1])
    ok = (g1 <= max_dt_s) & (g2 <= max_dt_s)
    a, b, r = traj[i1[ok]], traj[i2[ok]], rel[ok]
    c, s = np.cos(a[:, 3]), np.sin(a[:, 3])
    dx, dy = b[:, 1] - a[:, 1], b[:, 2] - a[:, 2]
    ex = c * dx + s * dy - r[:, 2]
    ey = -s * dx + c * dy - r[:, 3]
    et = (b[:, 3] - a[:, 3] - r[:, 4] + math.pi) % (2.0 * math.pi) - math.pi
    trans = np.hypot(ex, ey)
    rot = np.degrees(np.abs(et))
    matched = [relations[k] for k in np.flatnonzero(ok)]
    if not matched:
        nan = float("nan")
        return Score(len(relations), 0, nan, nan, nan, nan, nan, nan, None, None, trans, rot)
    return Score(
        relations=len(relations), matched=len(matched),
        trans_mean_m=float(trans.mean()), trans_std_m=float(trans.std()),
        trans_max_m=float(trans.max()),
        rot_mean_deg=float(rot.mean()), rot_std_deg=float(rot.std()),
        rot_max_deg=float(rot.max()),
        worst_trans=matched[int(np.argmax(trans))], worst_rot=matched[int(np.argmax(rot))],
        trans_errors_m=trans, rot_errors_deg=rot)
