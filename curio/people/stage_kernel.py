"""Compiled parts of the people stage (numba, ``nogil``): footprint to predicted people, and the
scoring of the candidate arcs.

For each candidate trajectory ``m``, each time step ``k`` and each person ``j``: the signed
distance (m, negative inside) from the person's predicted centre — constant velocity from
their tracked position — to the rover's footprint polygon at that pose, minus the person's
body radius. :func:`path_clearances` is the same for bodies whose future is known (another
rover's predicted path) instead of constant velocity, each with its own radius.

:func:`situation`, :func:`rollout_candidates`, :func:`score_candidates` and
:func:`combine_costs` are the arithmetic of :class:`curio.people.stage.PeopleStage` (who is
near, the candidates' rollouts, the comfortable distances and the costs), each in one pass: the
same floating-point operations in the same order as the numpy expressions they replace, so the
results are bit-for-bit the same (``tests/unit/test_people_stage_exact.py`` holds them to a
copy of those expressions). Work whose result cannot matter is skipped (a distance that is
neither a new closest approach nor within any comfortable distance). The sums over the people
are not here: numpy sums with pairwise blocks, and the stage leaves them to numpy.
All positions are in ``map`` (m), headings in rad, speeds in m/s, times in s from now; the
footprint is in ``base_link``. The first call compiles a kernel; numba caches the machine code
on disk.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = [
    "combine_costs", "path_clearances", "people_clearances", "rollout_candidates",
    "score_candidates", "score_params", "situation",
]

F64 = npt.NDArray[np.float64]

# score_candidates' ``params`` (score_params builds them in this order).
(P_X, P_Y, P_YAW, P_V_NOW, P_UP, P_RADIUS, P_MIN, P_PASSING, P_HEAD_GAIN, P_GROWTH,
 P_GROWTH_CAP, P_FLOOR, P_NARROW, P_ASSERTIVE, P_WALKING, P_AIM_X, P_AIM_Y, P_PROGRESS_SCALE,
 P_BEND_SCALE, P_KAPPA) = range(20)
# score_candidates' ``work`` planes (each (M, J)) and ``rows`` (each (M,)).
_WORST, _CLOSEST, _COMFORT, _UNSAFE = range(4)
_PROGRESS, _BEND, _BAD, _CLOSEST_ANY = range(4)


def score_params(*, pose: tuple[float, float, float], v_now: float, accel: float,
                 radius: float, min_distance: float, passing: float, head_gain: float,
                 growth: float, growth_cap: float, floor: float, narrow: bool, assertive: bool,
                 walking: float, aim: tuple[float, float], progress_scale: float,
                 bend_scale: float, kappa: float) -> F64:
    """:func:`score_candidates`' ``params``.

    Args:
        pose: the rover now (``map``, m, rad); ``v_now`` its speed (m/s), ``accel`` the
            acceleration limit (m/s², braking twice as hard).
        radius: the body radius around a track (m); ``min_distance``: nearer is unsafe (m);
            ``passing``: the comfortable distance (m), ``head_gain`` how much more in front of a
            walker (m).
        growth: how fast a walker's comfortable distance grows with the prediction (m/s), for
            ``growth_cap`` s.
        floor: what the comfortable distances shrink to (m) in a ``narrow`` passage (before
            the growth) and when ``assertive`` (after it).
        walking: faster than this (m/s) a track walks.
        aim: the aim relative to the rover (``map`` axes, m); ``progress_scale`` divides the
            progress towards it (m²), ``bend_scale`` the change of curvature from ``kappa``.
    """
    return np.array([pose[0], pose[1], pose[2], v_now, accel, radius, min_distance, passing,
                     head_gain, growth, growth_cap, floor, 1.0 if narrow else 0.0,
                     1.0 if assertive else 0.0, walking, aim[0], aim[1], progress_scale,
                     bend_scale, kappa], dtype=np.float64)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _edges(poly: F64) -> F64:  # pragma: no cover - compiled
    """Each edge of ``poly`` ``(E, 2)`` as ``(ax, ay, by, ex, ey, ex² + ey²)``: its start, the
    end's y, and the edge vector."""
    n = poly.shape[0]
    out = np.empty((n, 6))
    for i in range(n):
        ax, ay = poly[i, 0], poly[i, 1]
        bx, by = poly[(i + 1) % n, 0], poly[(i + 1) % n, 1]
        ex, ey = bx - ax, by - ay
        out[i, 0], out[i, 1], out[i, 2] = ax, ay, by
        out[i, 3], out[i, 4], out[i, 5] = ex, ey, ex * ex + ey * ey
    return out


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _polygon_distance(px: float, py: float, edges: F64) -> float:  # pragma: no cover
    """Signed distance (m) from a point to a polygon's boundary (negative inside); ``edges`` from
    :func:`_edges`. The square root is taken once, of the smallest square (the same number:
    a correctly rounded root is monotonic)."""
    best = math.inf
    inside = False
    for i in range(edges.shape[0]):
        ax, ay, by = edges[i, 0], edges[i, 1], edges[i, 2]
        ex, ey, ll = edges[i, 3], edges[i, 4], edges[i, 5]
        along = (px - ax) * ex + (py - ay) * ey
        # (Beyond either end the clamp gives 0 or 1 whatever the quotient: not divided.)
        if ll == 0.0 or along <= 0.0:
            u = 0.0
        elif along >= ll:
            u = 1.0
        else:
            u = max(0.0, min(1.0, along / ll))
        dx, dy = px - ax - u * ex, py - ay - u * ey
        d2 = dx * dx + dy * dy
        if d2 < best:
            best = d2
        if (ay > py) != (by > py):
            xc = ax + (py - ay) * ex / ey
            if px < xc:
                inside = not inside
    d = math.sqrt(best)
    return -d if inside else d


@njit(cache=True, nogil=True)  # type: ignore[misc]
def people_clearances(poses: F64, times: F64, people: F64, footprint: F64, radius: float,
                      out: F64) -> None:  # pragma: no cover - compiled
    """Fill ``out`` ``(M, K, J)`` with footprint-to-body distances (m).

    Args:
        poses: ``(M, K, 3)`` rover poses (x, y, yaw) in ``map``.
        times: ``(K,)`` seconds from now of each step.
        people: ``(J, 4)`` tracked people now: x, y, vx, vy (``map``, m, m/s).
        footprint: ``(E, 2)`` polygon in ``base_link``.
        radius: body radius assumed around each track, m.
    """
    edges = _edges(footprint)
    m_n, k_n = poses.shape[0], poses.shape[1]
    for m in range(m_n):
        for k in range(k_n):
            x, y, yaw = poses[m, k, 0], poses[m, k, 1], poses[m, k, 2]
            c, s = math.cos(yaw), math.sin(yaw)
            t = times[k]
            for j in range(people.shape[0]):
                dx = people[j, 0] + people[j, 2] * t - x
                dy = people[j, 1] + people[j, 3] * t - y
                out[m, k, j] = _polygon_distance(c * dx + s * dy, -s * dx + c * dy,
                                                 edges) - radius


@njit(cache=True, nogil=True)  # type: ignore[misc]
def path_clearances(poses: F64, futures: F64, footprint: F64, radii: F64,
                    out: F64) -> None:  # pragma: no cover - compiled
    """Fill ``out`` ``(M, K, J)`` with footprint-to-body distances (m) to bodies whose
    positions at each step are known.

    Args:
        poses: ``(M, K, 3)`` rover poses (x, y, yaw) in ``map``.
        futures: ``(J, K, 2)`` each body's predicted centre (``map``, m) at each step.
        footprint: ``(E, 2)`` polygon in ``base_link``.
        radii: ``(J,)`` each body's radius, m.
    """
    edges = _edges(footprint)
    m_n, k_n = poses.shape[0], poses.shape[1]
    for m in range(m_n):
        for k in range(k_n):
            x, y, yaw = poses[m, k, 0], poses[m, k, 1], poses[m, k, 2]
            c, s = math.cos(yaw), math.sin(yaw)
            for j in range(futures.shape[0]):
                dx = futures[j, k, 0] - x
                dy = futures[j, k, 1] - y
                out[m, k, j] = _polygon_distance(c * dx + s * dy, -s * dx + c * dy,
                                                 edges) - radii[j]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def situation(now_d: F64, pose: F64, people: F64, near_m: float,
              walking_mps: float) -> tuple[bool, bool]:  # pragma: no cover - compiled
    """Whether someone ahead is near (nearer than ``near_m`` and not walking away faster than
    ``walking_mps``) and whether someone ahead walks straight at the rover (faster than
    ``walking_mps``, within 1.5 m).

    Args:
        now_d: ``(1, 1, J)`` :func:`people_clearances` from the rover now (m).
        pose: the rover now, ``(x, y, cos yaw, sin yaw)`` (``map``, m).
        people: ``(J, 6)`` as :meth:`~curio.people.stage.PeopleStage.people_near` gives them.
    """
    x, y, c, s = pose[0], pose[1], pose[2], pose[3]
    near = approaching = False
    for j in range(people.shape[0]):
        d = now_d[0, 0, j] - people[j, 5]
        ahead = (people[j, 0] - x) * c + (people[j, 1] - y) * s
        towards = people[j, 2] * c + people[j, 3] * s
        if d < near_m and ahead > 0.0 and towards < walking_mps:
            near = True
        if ahead > 0 and towards < -walking_mps and d < 1.5:
            approaching = True
    return near, approaching


@njit(cache=True, nogil=True, inline="always")  # type: ignore[misc]
def _minimum(a: float, b: float) -> float:  # pragma: no cover - compiled
    """``np.minimum`` of two numbers (NaN wins)."""
    return a if a <= b or a != a else b


@njit(cache=True, nogil=True, inline="always")  # type: ignore[misc]
def _maximum(a: float, b: float) -> float:  # pragma: no cover - compiled
    """``np.maximum`` of two numbers (NaN wins)."""
    return a if a >= b or a != a else b


@njit(cache=True, nogil=True, error_model="numpy")  # type: ignore[misc]
def rollout_candidates(lo: int, hi: int, cands: F64, times: F64, params: F64,
                       poses: F64) -> None:  # pragma: no cover - compiled
    """Candidates ``lo`` to ``hi`` rolled out into ``poses`` ``(M, K, 3)`` (``map``, m, rad)
    at ``times`` ``(K,)``, s from now: the speed ramps from ``v_now`` under the acceleration
    limit (braking twice as hard), the curvature is ``cands[m, 1]`` until ``cands[m, 2]`` and
    ``cands[m, 3]`` after; the heading and the position are summed step by step along the
    arc's midpoints. ``params`` from :func:`score_params`."""
    for m in range(lo, hi):
        _rollout(m, cands, times, params, poses)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")  # type: ignore[misc]
def _rollout(m: int, cands: F64, times: F64, params: F64,
             poses: F64) -> None:  # pragma: no cover - compiled
    """Candidate ``m`` of :func:`rollout_candidates`."""
    v_now, up = params[P_V_NOW], params[P_UP]
    vc = cands[m, 0]
    acc = up if vc >= v_now else -2.0 * up
    t_ramp = abs(vc - v_now) / abs(acc)
    x0, y0, yaw = params[P_X], params[P_Y], params[P_YAW]
    poses[m, 0, 0], poses[m, 0, 1], poses[m, 0, 2] = x0 + 0.0, y0 + 0.0, yaw + 0.0
    s_prev = 0.0
    cth = cx = cy = 0.0
    last_mid = cm = sm = math.nan
    for k in range(times.shape[0]):
        t = times[k]
        tr = _minimum(t, t_ramp)
        s = v_now * tr + 0.5 * acc * tr * tr + vc * _maximum(t - t_ramp, 0.0)
        if k > 0:
            i = k - 1  # the step from times[i] to times[k]
            ds = s - s_prev
            kap = cands[m, 1] if times[i] < cands[m, 2] else cands[m, 3]
            mid = poses[m, i, 2] + 0.5 * kap * ds
            if mid != last_mid or mid == 0.0:  # (the same heading: the same cos and sin)
                cm, sm = math.cos(mid), math.sin(mid)
                last_mid = mid
            step_th, step_x, step_y = kap * ds, ds * cm, ds * sm
            if i == 0:  # numpy's cumsum starts from its first term, not from 0.0 + it
                cth, cx, cy = step_th, step_x, step_y
            else:
                cth, cx, cy = cth + step_th, cx + step_x, cy + step_y
            poses[m, k, 0], poses[m, k, 1], poses[m, k, 2] = x0 + cx, y0 + cy, yaw + cth
        s_prev = s


@njit(cache=True, nogil=True, error_model="numpy")  # type: ignore[misc]
def score_candidates(lo: int, hi: int, cands: F64, times: F64, weights: F64, people: F64,
                     known: F64, footprint: F64, params: F64, persons: int, poses: F64,
                     work: F64, rows: F64) -> None:  # pragma: no cover - compiled
    """Score candidates ``lo`` to ``hi`` (rolled out into ``poses`` by
    :func:`rollout_candidates`) against the people, every other step of ``times``; row 3
    (stopping) is the reference and must be among the rows scored (now or by an earlier call
    on the same arrays).

    Args:
        cands: ``(M, 4)`` target speed (m/s), first curvature (1/m), when it ends (s), the
            curvature after it.
        times: ``(K,)`` s from now; ``weights`` ``(K,)``: how much each step's shortfall weighs.
        people: ``(J, 6)`` as :meth:`~curio.people.stage.PeopleStage.people_near` gives them:
            the people, then the movers.
        known: ``(M, (K + 1) // 2, N)`` the distances (m) to the last ``N`` rows of ``people``
            (the movers, whose futures are known: :func:`path_clearances`) at those steps.
        footprint: ``(E, 2)`` polygon in ``base_link``.
        params: from :func:`score_params`.
        persons: the rows of ``people`` that are people (a walker's prediction grows).
        poses: ``(M, K, 3)``: the rollouts (``map``, m, rad).
        work: out ``(4, M, J)``: each person's worst weighted squared shortfall and closest
            approach (m), then the terms of the comfort and the safety sums.
        rows: out ``(4, M)``: progress, bend, 1.0 where the candidate drives at someone (the
            hard rule), and the closest approach to anyone (m).
    """
    edges = _edges(footprint)
    radius, min_d = params[P_RADIUS], params[P_MIN]
    passing, head_gain = params[P_PASSING], params[P_HEAD_GAIN]
    growth, cap, floor_m = params[P_GROWTH], params[P_GROWTH_CAP], params[P_FLOOR]
    narrow, assertive = params[P_NARROW] > 0.5, params[P_ASSERTIVE] > 0.5
    walking = params[P_WALKING]
    k_n, j_n = times.shape[0], people.shape[0]
    first_mover = j_n - known.shape[2]
    # Per person: the speed, whether the comfortable distance depends on where the rover is
    # (someone walking: ``front``), whether it grows with the prediction, and the largest it can
    # be before that growth (``passing + head_gain * front`` rounds monotonically in front).
    speed = np.empty(j_n)
    fronted = np.empty(j_n, dtype=np.bool_)
    grows = np.empty(j_n, dtype=np.bool_)
    most = np.empty(j_n)
    for j in range(j_n):
        walked = people[j, 4] > 0.5
        speed[j] = math.hypot(people[j, 2], people[j, 3])
        fronted[j] = speed[j] > walking
        grows[j] = fronted[j] and walked and j < persons
        most[j] = passing + _maximum(head_gain, 0.0) if walked else min_d
    box_x0, box_x1 = footprint[:, 0].min(), footprint[:, 0].max()
    box_y0, box_y1 = footprint[:, 1].min(), footprint[:, 1].max()
    for m in range(lo, hi):
        for j in range(j_n):
            work[_WORST, m, j] = -math.inf
            work[_CLOSEST, m, j] = math.inf
        last_yaw = c = s = math.nan
        for k in range(0, k_n, 2):
            x, y, yaw = poses[m, k, 0], poses[m, k, 1], poses[m, k, 2]
            if yaw != last_yaw or yaw == 0.0:  # (the same heading: the same cos and sin)
                c, s = math.cos(yaw), math.sin(yaw)
                last_yaw = yaw
            t, w = times[k], weights[k]
            g = growth * _minimum(t, cap)
            for j in range(j_n):
                vx, vy = people[j, 2], people[j, 3]
                cx, cy = people[j, 0] + vx * t, people[j, 1] + vy * t  # predicted centre
                # No comfortable distance reaches farther than this (the rounded sums below grow
                # monotonically with front and g).
                reach = most[j] + _maximum(g, 0.0)
                if j >= first_mover:  # a mover: along its known future
                    dist = known[m, k // 2, j - first_mover]
                else:
                    dx, dy = cx - x, cy - y
                    bx, by = c * dx + s * dy, -s * dx + c * dy  # base_link
                    # Farther from the box round the footprint than that and than the closest
                    # yet (with room for rounding): no shortfall and no new closest, whatever
                    # the exact distance.
                    beyond = _maximum(work[_CLOSEST, m, j], reach) + radius + 1e-6
                    if 0.0 < beyond < math.inf:
                        qx = _maximum(_maximum(box_x0 - bx, bx - box_x1), 0.0)
                        qy = _maximum(_maximum(box_y0 - by, by - box_y1), 0.0)
                        if qx * qx + qy * qy >= beyond * beyond * (1.0 + 1e-8):
                            if work[_WORST, m, j] < 0.0:
                                work[_WORST, m, j] = 0.0
                            continue
                    dist = _polygon_distance(bx, by, edges) - radius
                if dist < work[_CLOSEST, m, j] or dist != dist:
                    work[_CLOSEST, m, j] = dist
                if dist >= reach:  # the shortfall is 0, whatever front is
                    if work[_WORST, m, j] < 0.0:
                        work[_WORST, m, j] = 0.0
                    continue
                # The comfortable distance (the arithmetic of the numpy expressions it replaces).
                front = 0.0
                if fronted[j]:
                    rx, ry = x - cx, y - cy
                    front = (vx * rx + vy * ry) / (math.hypot(rx, ry) * _maximum(speed[j], 1e-9))
                    if front != front:
                        front = 0.0
                    front = _minimum(_maximum(front, 0.0), 1.0)
                req = passing + head_gain * front if people[j, 4] > 0.5 else min_d
                if narrow:
                    req = _minimum(req, floor_m)
                req = req + g * (1.0 if grows[j] else 0.0)
                if assertive:
                    req = _minimum(req, floor_m)
                short = _maximum(req - dist, 0.0)
                worst = short * short * w
                if worst > work[_WORST, m, j] or worst != worst:
                    work[_WORST, m, j] = worst
        rows[_PROGRESS, m] = ((poses[m, k_n - 1, 0] - params[P_X]) * params[P_AIM_X]
                              + (poses[m, k_n - 1, 1] - params[P_Y]) * params[P_AIM_Y]) \
            / params[P_PROGRESS_SCALE]
        rows[_BEND, m] = abs(cands[m, 1] - params[P_KAPPA]) / params[P_BEND_SCALE]
    for m in range(lo, hi):  # against stopping (row 3)
        bad = False
        closest_any = math.inf
        for j in range(j_n):
            worst = work[_WORST, m, j]
            work[_COMFORT, m, j] = _maximum(worst - work[_WORST, 3, j], 0.0) + 0.2 * worst
            closest = work[_CLOSEST, m, j]
            short = _maximum(min_d - closest, 0.0)
            work[_UNSAFE, m, j] = short * short
            if closest < min_d and closest < work[_CLOSEST, 3, j] - 0.02:
                bad = True
            if closest < closest_any or closest != closest:
                closest_any = closest
        rows[_BAD, m] = 1.0 if bad and m != 3 else 0.0
        rows[_CLOSEST_ANY, m] = closest_any


@njit(cache=True, nogil=True)  # type: ignore[misc]
def combine_costs(sums: F64, rows: F64, weights: F64,
                  out: F64) -> None:  # pragma: no cover - compiled
    """Each candidate's cost into ``out`` ``(M,)``: ``sums`` ``(2, M)`` the comfort and safety
    sums (numpy's, of :func:`score_candidates`' terms), ``rows`` its ``(4, M')`` rows
    (``M' >= M``), ``weights`` those of safety, comfort, progress and bend; infinite for a
    candidate that drives at someone."""
    for m in range(out.shape[0]):
        cost = (weights[0] * sums[1, m] + weights[1] * sums[0, m]
                - weights[2] * rows[_PROGRESS, m] + weights[3] * rows[_BEND, m])
        out[m] = math.inf if rows[_BAD, m] > 0.5 else cost
