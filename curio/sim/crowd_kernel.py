"""Compiled social-force accelerations (numba, ``nogil``): Helbing & Molnár (1995).

For each visitor α (positions and velocities in ``map``, metres, m/s):

* **driving force** ``(v0·e − v) / τ`` towards the desired direction ``e`` at the desired
  speed ``v0`` (relaxation time ``τ``);
* **repulsion from every other visitor** β: the potential ``V(b) = V0·exp(−b/σ)`` whose
  equipotential lines are ellipses stretched along β's motion, with
  ``2b = sqrt((|r| + |r − s·e_β|)² − s²)``, ``r = r_α − r_β``, ``s = |v_β|·Δt`` (β's step);
  the force is ``−∇_r V`` (analytic gradient), weighted by ``c`` when β is outside α's field
  of view (``cos φ``);
* **repulsion from the rover** as from a visitor of radius ``rover_radius`` moving with the
  rover's velocity, ``rover_gain`` times as strong, scaled per visitor by its attention
  (a distracted visitor reacts late and little; the rover state a visitor reacts to is the one
  it last *perceived*, a reaction time ago);
* **repulsion from walls** ``U(d) = U0·exp(−d/R)`` from the nearest wall point.

:func:`crowd_inputs` and :func:`crowd_advance` do the crowd step's per-visitor arithmetic
around it (desired velocities, wall lookups, the speed cap, refused steps) in one pass each,
with the same operations in the same order as the numpy code they replace (bit for bit).

The first call compiles the kernel (a second or two); numba caches the machine code on disk.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["cast_discs", "count_hits", "crowd_advance", "crowd_inputs",
           "segment_min_clearance", "social_accelerations"]

F64 = npt.NDArray[np.float64]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _ellipse_force(rx: float, ry: float, ebx: float, eby: float, s: float, shrink: float,
                   v0_over_sigma: float, sigma: float) -> tuple[float, float]:  # pragma: no cover
    """``−∇V(b(r))`` for the elliptical potential; ``shrink`` is subtracted from both focal
    distances (the other body's radius beyond a point)."""
    p = math.sqrt(rx * rx + ry * ry)
    if p < 1e-6:
        return 0.0, 0.0
    qx = rx - s * ebx
    qy = ry - s * eby
    q = math.sqrt(qx * qx + qy * qy)
    if q < 1e-6:
        q = 1e-6
    ps = max(p - shrink, 0.02)
    qs = max(q - shrink, 0.02)
    big = (ps + qs) * (ps + qs) - s * s
    b = 0.5 * math.sqrt(max(big, 1e-8))
    b = max(b, 1e-3)
    # ∂b/∂r = (p+q)(r/p + q_vec/q) / (4b), with the shrunk focal sum.
    gx = (ps + qs) * (rx / p + qx / q) / (4.0 * b)
    gy = (ps + qs) * (ry / p + qy / q) / (4.0 * b)
    mag = v0_over_sigma * math.exp(-b / sigma)
    return mag * gx, mag * gy


@njit(cache=True, nogil=True)  # type: ignore[misc]
def social_accelerations(pos: F64, vel: F64, desired: F64, tau: float, walls: F64,
                         rover: F64, rover_weight: F64, params: F64,
                         out: F64) -> None:  # pragma: no cover - compiled
    """Write each visitor's acceleration (m/s²) into ``out`` ``(N, 2)``.

    Args:
        pos, vel: ``(N, 2)`` positions and velocities.
        desired: ``(N, 2)`` desired velocities ``v0·e``.
        tau: relaxation time, seconds.
        walls: ``(N, 3)`` nearest wall point (x, y) and the distance to its surface (m).
        rover: ``(N, 5)`` the rover as each visitor last perceived it: x, y, vx, vy, radius.
        rover_weight: ``(N,)`` how strongly each visitor avoids the rover (0 = not at all).
        params: V0 (m²/s²), σ (m), Δt (s), U0 (m²/s²), R (m), cos φ, c, cutoff (m), rover_gain.
    """
    v0, sigma, dt_hm, u0, rr, cos_phi, c_out, cutoff, rover_gain = (
        params[0], params[1], params[2], params[3], params[4], params[5], params[6],
        params[7], params[8])
    n = pos.shape[0]
    k = v0 / sigma
    for a in range(n):
        ax = (desired[a, 0] - vel[a, 0]) / tau
        ay = (desired[a, 1] - vel[a, 1]) / tau
        dnorm = math.sqrt(desired[a, 0] ** 2 + desired[a, 1] ** 2)
        ex = desired[a, 0] / dnorm if dnorm > 1e-6 else 0.0
        ey = desired[a, 1] / dnorm if dnorm > 1e-6 else 0.0
        for b in range(n):
            if b == a:
                continue
            rx = pos[a, 0] - pos[b, 0]
            ry = pos[a, 1] - pos[b, 1]
            if abs(rx) > cutoff or abs(ry) > cutoff:
                continue
            sp = math.sqrt(vel[b, 0] ** 2 + vel[b, 1] ** 2)
            ebx = vel[b, 0] / sp if sp > 0.05 else 0.0
            eby = vel[b, 1] / sp if sp > 0.05 else 0.0
            fx, fy = _ellipse_force(rx, ry, ebx, eby, sp * dt_hm if sp > 0.05 else 0.0, 0.0,
                                    k, sigma)
            # Field of view: β behind α weighs c.
            w = 1.0 if (-rx * ex - ry * ey) >= math.sqrt(rx * rx + ry * ry) * cos_phi else c_out
            ax += w * fx
            ay += w * fy
        if rover_weight[a] > 0.0:
            rx = pos[a, 0] - rover[a, 0]
            ry = pos[a, 1] - rover[a, 1]
            if abs(rx) < cutoff and abs(ry) < cutoff:
                sp = math.sqrt(rover[a, 2] ** 2 + rover[a, 3] ** 2)
                ebx = rover[a, 2] / sp if sp > 0.02 else 0.0
                eby = rover[a, 3] / sp if sp > 0.02 else 0.0
                fx, fy = _ellipse_force(rx, ry, ebx, eby, sp * dt_hm if sp > 0.02 else 0.0,
                                        rover[a, 4], k * rover_gain, sigma)
                ax += rover_weight[a] * fx
                ay += rover_weight[a] * fy
        d = walls[a, 2]
        wx = pos[a, 0] - walls[a, 0]
        wy = pos[a, 1] - walls[a, 1]
        wn = math.sqrt(wx * wx + wy * wy)
        if wn > 1e-6 and d < 2.0:
            mag = u0 / rr * math.exp(-max(d, 0.0) / rr)
            ax += mag * wx / wn
            ay += mag * wy / wn
        out[a, 0] = ax
        out[a, 1] = ay


@njit(cache=True, nogil=True)  # type: ignore[misc]
def segment_min_clearance(clearance: F64, ox: float, oy: float, res: float, ax: float,
                          ay: float, bx: float, by: float,
                          need: float) -> bool:  # pragma: no cover - compiled
    """Whether every point of the segment a→b (map metres) has at least ``need`` metres of
    clearance in the grid ``clearance`` (rows = y; cell (0, 0)'s corner at (ox, oy))."""
    h, w = clearance.shape
    length = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
    n = max(2, math.ceil(length / (0.5 * res)) + 1)
    for i in range(n):
        t = i / (n - 1)
        col = math.floor((ax + t * (bx - ax) - ox) / res)
        row = math.floor((ay + t * (by - ay) - oy) / res)
        if row < 0 or row >= h or col < 0 or col >= w or clearance[row, col] < need:
            return False
    return True


@njit(cache=True, nogil=True)  # type: ignore[misc]
def cast_discs(ox: float, oy: float, dx: F64, dy: F64, discs: F64,
               ranges: F64) -> None:  # pragma: no cover - compiled
    """Shorten ``ranges`` (m, in place) where a ray from (ox, oy) along (dx, dy) hits one of
    the ``(C, 3)`` discs (x, y, radius) first; a ray starting inside a disc reads 0."""
    for j in range(discs.shape[0]):
        cx = discs[j, 0] - ox
        cy = discs[j, 1] - oy
        r = discs[j, 2]
        c = cx * cx + cy * cy - r * r
        d = math.sqrt(cx * cx + cy * cy)
        if d <= r:
            for i in range(dx.shape[0]):
                ranges[i] = 0.0
            continue
        # Only beams within the disc's angular half-width can hit it.
        cos_half = math.cos(math.asin(min(1.0, r / d)))
        for i in range(dx.shape[0]):
            b = dx[i] * cx + dy[i] * cy
            if b <= 0.0:
                continue
            if b / d < cos_half:
                continue
            disc = b * b - c
            if disc < 0.0:
                continue
            t = b - math.sqrt(disc)
            if 0.0 <= t < ranges[i]:
                ranges[i] = t


@njit(cache=True, nogil=True)  # type: ignore[misc]
def count_hits(points: F64, centres: F64, radius: float,
               out: npt.NDArray[np.int64]) -> None:  # pragma: no cover - compiled
    """For each ``(N, 2)`` centre, how many ``(K, 2)`` points lie within ``radius`` of it."""
    r2 = radius * radius
    for j in range(centres.shape[0]):
        n = 0
        cx = centres[j, 0]
        cy = centres[j, 1]
        for k in range(points.shape[0]):
            ddx = points[k, 0] - cx
            ddy = points[k, 1] - cy
            if ddx * ddx + ddy * ddy <= r2:
                n += 1
        out[j] = n


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _wall_at(x: float, y: float, clearance: F64, near_row: npt.NDArray[np.int64],
             near_col: npt.NDArray[np.int64], ox: float, oy: float,
             res: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """The centre of the blocked cell nearest to map point (x, y) and the clearance there (m);
    outside the grid: the point itself and 0."""
    h, w = clearance.shape
    col = math.floor((x - ox) / res)
    row = math.floor((y - oy) / res)
    if row < 0 or row >= h or col < 0 or col >= w:
        return x, y, 0.0
    return (ox + (near_col[row, col] + 0.5) * res, oy + (near_row[row, col] + 0.5) * res,
            clearance[row, col])


@njit(cache=True, nogil=True)  # type: ignore[misc]
def crowd_inputs(pos: F64, steer: F64, speed: F64, rover_x: float, rover_y: float,
                 notice: F64, attention: F64, clearance: F64, near_row: npt.NDArray[np.int64],
                 near_col: npt.NDArray[np.int64], ox: float, oy: float, res: float,
                 desired: F64, walls: F64, here_clear: F64,
                 weight: F64) -> None:  # pragma: no cover - compiled
    """The inputs of :func:`social_accelerations` for ``(N, 2)`` positions ``pos`` (map, m).

    Writes, per visitor: ``desired`` ``(N, 2)`` its desired velocity (m/s, map): ``speed``
    (m/s) towards ``steer`` (map), zero within 0.05 m of it; ``walls`` ``(N, 3)`` the nearest
    blocked cell's centre (map) and the distance to that cell's surface (m, half a cell
    ``res`` nearer than its centre); ``here_clear`` ``(N,)`` the clearance (m) of the cell it
    stands in (0 outside the grid); ``weight`` ``(N,)`` its ``attention`` if the rover at
    (``rover_x``, ``rover_y``) is within its ``notice`` distance (m), else 0.
    """
    half = 0.5 * res
    for i in range(pos.shape[0]):
        x = pos[i, 0]
        y = pos[i, 1]
        tx = steer[i, 0] - x
        ty = steer[i, 1] - y
        dist = max(np.hypot(tx, ty), 1e-9)
        f = (speed[i] if dist > 0.05 else 0.0) / dist
        desired[i, 0] = tx * f
        desired[i, 1] = ty * f
        wx, wy, c = _wall_at(x, y, clearance, near_row, near_col, ox, oy, res)
        walls[i, 0] = wx
        walls[i, 1] = wy
        walls[i, 2] = np.hypot(x - wx, y - wy) - half
        here_clear[i] = c
        d = np.hypot(x - rover_x, y - rover_y)
        weight[i] = attention[i] if d <= notice[i] else 0.0


@njit(cache=True, nogil=True)  # type: ignore[misc]
def crowd_advance(pos: F64, vel: F64, acc: F64, dt: float, cap: F64, here_clear: F64,
                  stop_clear: float, clearance: F64, near_row: npt.NDArray[np.int64],
                  near_col: npt.NDArray[np.int64], ox: float, oy: float, res: float,
                  rover_x: float, rover_y: float, near_m: float, new: F64, new_vel: F64,
                  near: npt.NDArray[np.bool_]) -> None:  # pragma: no cover - compiled
    """One explicit-Euler step of ``dt`` seconds from ``pos``, ``vel`` (map, m, m/s) with the
    accelerations ``acc`` (m/s²), each speed capped at ``cap`` (m/s) → ``new``, ``new_vel``.

    A step is refused (the visitor stays, velocity 0) where it ends in a cell with less than
    ``stop_clear`` metres of clearance and less than ``here_clear`` (where it stands).
    ``near`` tells which visitors end within ``near_m`` of the rover's centre (map).
    """
    for i in range(pos.shape[0]):
        vx = vel[i, 0] + acc[i, 0] * dt
        vy = vel[i, 1] + acc[i, 1] * dt
        k = min(1.0, cap[i] / max(np.hypot(vx, vy), 1e-9))
        vx *= k
        vy *= k
        nx = pos[i, 0] + vx * dt
        ny = pos[i, 1] + vy * dt
        c = _wall_at(nx, ny, clearance, near_row, near_col, ox, oy, res)[2]
        if c < stop_clear and c < here_clear[i]:
            nx = pos[i, 0]
            ny = pos[i, 1]
            vx = 0.0
            vy = 0.0
        new[i, 0] = nx
        new[i, 1] = ny
        new_vel[i, 0] = vx
        new_vel[i, 1] = vy
        near[i] = np.hypot(nx - rover_x, ny - rover_y) < near_m
