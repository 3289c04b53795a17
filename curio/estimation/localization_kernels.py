"""Compiled inner loops of the localiser (numba): distance-field lookups, the per-point
terms of the scan match, the beam ends in grid-local metres and the particles' heaviest bin.

Each kernel computes, element by element and in the same order, the arithmetic of the numpy
expressions it replaces in :mod:`curio.estimation.localization` (no fused multiply-adds, no
reassociation), so the results are identical to the last bit; the transcendental functions
(``cos``, ``sin``, ``exp``, ``log``) and the reductions (sums, means, matrix products) stay in
numpy, whose rounding the kernels do not try to reproduce. What the kernels save is numpy's
per-call overhead: a lookup of 60–200 points was some 30 array operations.

Grid conventions (those of :class:`~curio.estimation.localization.DistanceField`): points in
``map`` metres; ``(ox, oy)`` the grid origin (an unrotated grid); cell ``(r, c)`` covers
``[c, c + 1) × [r, r + 1)`` cells from the origin; ``dist`` the ``(H, W)`` distance field in
metres; points outside read ``max_dist``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit  # type: ignore[import-untyped]

__all__ = ["beam_evidence", "ends_local", "heaviest_bin",
           "lookup_grad_points", "lookup_points", "lookup_poses", "match_terms"]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _nearest(dist, ox, oy, res, max_dist, x, y):  # type: ignore[no-untyped-def]
    """Nearest-cell distance at the map point ``(x, y)``, metres."""
    h, w = dist.shape
    fx = math.floor((x - ox) / res)
    fy = math.floor((y - oy) / res)
    if not (fx >= 0.0 and fx < w and fy >= 0.0 and fy < h):  # also NaN
        return max_dist
    return dist[int(fy), int(fx)]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def lookup_points(dist, ox, oy, res, max_dist, x, y, out):  # type: ignore[no-untyped-def]
    """``out[i]`` = nearest-cell distance at ``(x[i], y[i])`` (1-D arrays), metres."""
    for i in range(x.shape[0]):
        out[i] = _nearest(dist, ox, oy, res, max_dist, x[i], y[i])


@njit(cache=True, nogil=True)  # type: ignore[misc]
def lookup_poses(dist, ox, oy, res, max_dist, x0, y0, cos0, sin0,  # type: ignore[no-untyped-def]
                 px, py, out):
    """``out[m, i]`` = nearest-cell distance at point ``(px[i], py[i])`` (``base_link``) seen
    from pose ``m``: position ``(x0[m], y0[m])``, heading cosine ``cos0[m]`` and sine
    ``sin0[m]``; the map point is ``(x0 + cos·px − sin·py, y0 + sin·px + cos·py)``."""
    for m in range(x0.shape[0]):
        xm = x0[m]
        ym = y0[m]
        cm = cos0[m]
        sm = sin0[m]
        for i in range(px.shape[0]):
            wx = xm + cm * px[i] - sm * py[i]
            wy = ym + sm * px[i] + cm * py[i]
            out[m, i] = _nearest(dist, ox, oy, res, max_dist, wx, wy)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _bilinear(dist, ox, oy, res, max_dist, x, y):  # type: ignore[no-untyped-def]
    """Bilinear distance and its gradient (d/dx, d/dy in grid axes) at ``(x, y)``."""
    h, w = dist.shape
    fx = (x - ox) / res - 0.5
    fy = (y - oy) / res - 0.5
    c0f = math.floor(fx)
    r0f = math.floor(fy)
    if not (r0f >= 0.0 and r0f < h - 1 and c0f >= 0.0 and c0f < w - 1):  # also NaN
        return max_dist, 0.0, 0.0
    c0 = int(c0f)
    r0 = int(r0f)
    tx = fx - c0f
    ty = fy - r0f
    d00 = dist[r0, c0]
    d01 = dist[r0, c0 + 1]
    d10 = dist[r0 + 1, c0]
    d11 = dist[r0 + 1, c0 + 1]
    val = (d00 * (1 - tx) * (1 - ty) + d01 * tx * (1 - ty) + d10 * (1 - tx) * ty
           + d11 * tx * ty)
    gx = ((d01 - d00) * (1 - ty) + (d11 - d10) * ty) / res
    gy = ((d10 - d00) * (1 - tx) + (d11 - d01) * tx) / res
    return val, gx, gy


@njit(cache=True, nogil=True)  # type: ignore[misc]
def lookup_grad_points(dist, ox, oy, res, max_dist, x, y, val, gx, gy):  # type: ignore[no-untyped-def]
    """Bilinear distance and gradient at ``(x[i], y[i])`` into ``val``, ``gx``, ``gy``."""
    for i in range(x.shape[0]):
        val[i], gx[i], gy[i] = _bilinear(dist, ox, oy, res, max_dist, x[i], y[i])


@njit(cache=True, nogil=True)  # type: ignore[misc]
def match_terms(dist, ox, oy, res, max_dist, x, y, c, s, px, py, half,  # type: ignore[no-untyped-def]
                max_residual, huber, r_out, j_out, jw_out):
    """The Gauss–Newton terms of one scan-match iteration at pose ``(x, y)``, heading cosine
    ``c`` and sine ``s``, for the points ``(px, py)`` in ``base_link``.

    A point is used when its residual ``r`` (interpolated distance minus ``half``) is below
    ``max_residual`` in magnitude; for the ``k`` used points, in order, it writes the residual
    to ``r_out[:k]``, the Jacobian rows ``(∂r/∂x, ∂r/∂y, ∂r/∂θ)`` to ``j_out[:k]`` and the
    Huber-weighted rows (weight 1 within ``huber``, ``huber / |r|`` beyond) to ``jw_out[:k]``.

    Returns:
        ``k``.
    """
    k = 0
    for i in range(px.shape[0]):
        wx = x + c * px[i] - s * py[i]
        wy = y + s * px[i] + c * py[i]
        d, gx, gy = _bilinear(dist, ox, oy, res, max_dist, wx, wy)
        r = d - half
        if not abs(r) < max_residual:
            continue
        jt = gx * (-s * px[i] - c * py[i]) + gy * (c * px[i] - s * py[i])
        a = abs(r)
        wgt = 1.0 if a <= huber else huber / max(a, 1e-12)
        r_out[k] = r
        j_out[k, 0] = gx
        j_out[k, 1] = gy
        j_out[k, 2] = jt
        jw_out[k, 0] = gx * wgt
        jw_out[k, 1] = gy * wgt
        jw_out[k, 2] = jt * wgt
        k += 1
    return k


@njit(cache=True, nogil=True)  # type: ignore[misc]
def heaviest_bin(p, w, size, sel):  # type: ignore[no-untyped-def]
    """Mark in ``sel`` (bool) the particles ``p`` (rows x, y, … in ``map`` metres; weights ``w``) in
    the heaviest ``size`` × ``size`` bin; the bins are keyed ``floor(x / size) · 100 003 +
    floor(y / size)`` (int64), their masses summed particle by particle in index order, and of
    equal masses the bin with the smallest key wins — what ``np.unique(key,
    return_inverse=True)``, ``np.bincount`` with the weights and ``np.argmax`` give, to the
    bit (a NaN mass wins, as in ``np.argmax``)."""
    n = p.shape[0]
    key = np.empty(n, dtype=np.int64)
    for i in range(n):
        key[i] = (np.int64(math.floor(p[i, 0] / size)) * 100_003
                  + np.int64(math.floor(p[i, 1] / size)))
    order = np.argsort(key)
    rank = np.empty(n, dtype=np.int64)  # the bin's place among the distinct keys, ascending
    nb = 0
    for j in range(n):
        i = order[j]
        if j > 0 and key[i] != key[order[j - 1]]:
            nb += 1
        rank[i] = nb
    mass = np.zeros(nb + 1)
    for i in range(n):
        mass[rank[i]] += w[i]
    best = 0
    if not math.isnan(mass[0]):
        for b in range(1, nb + 1):
            if math.isnan(mass[b]):
                best = b
                break
            if mass[b] > mass[best]:
                best = b
    for i in range(n):
        sel[i] = rank[i] == best


@njit(cache=True, nogil=True)  # type: ignore[misc]
def ends_local(x, y, c, s, pts, ox, oy, ex, ey):  # type: ignore[no-untyped-def]
    """Grid-local metres of the points ``pts`` ``(N, 2)`` (``base_link``) seen from the pose at
    ``(x, y)`` in ``map``, heading cosine ``c`` and sine ``s``, on an unrotated grid whose origin
    is ``(ox, oy)``: ``ex[i] = (x + c·px − s·py) − ox``, ``ey[i] = (y + s·px + c·py) − oy``."""
    for i in range(pts.shape[0]):
        ex[i] = (x + c * pts[i, 0] - s * pts[i, 1]) - ox
        ey[i] = (y + s * pts[i, 0] + c * pts[i, 1]) - oy


@njit(cache=True, nogil=True)  # type: ignore[misc]
def beam_evidence(dist, free, res, max_dist, lx, ly, x, y, inlier_m,  # type: ignore[no-untyped-def]
                  out, end_dist):
    """Sort beams from the laser at ``(lx, ly)`` to their ends ``(x[i], y[i])`` (grid-local
    metres: the origin corner at (0, 0), unrotated) by what they say about the pose; write
    ``end_dist[i]``, the nearest-cell distance at the end (``max_dist`` off the grid, as
    :func:`lookup_points` reads it), and ``out[i]`` (int8):

    * ``ON_WALL`` (1): the end lies within ``inlier_m`` of a wall face (the nearest-cell
      distance less half a cell, as the fit counts it);
    * ``IN_FRONT`` (2): the end lies in a known-free cell and the ray to it crosses no
      occupied cell before its last ``inlier_m`` + one cell — something the map does not hold
      stands there (a visitor, a bag): it neither supports nor contradicts the pose;
    * ``AGAINST`` (0): the rest — the ray went through a wall, or ended in unknown space or
      off the map.

    The ray is marched on the distance field (sphere tracing): each step is the free radius
    the field guarantees around the point (the distance less one and a half cells, at least
    half a cell), so a wall one cell thick is not stepped over.
    """
    h, w = dist.shape
    half = 0.5 * res
    for i in range(x.shape[0]):
        out[i] = 0
        ex = x[i]
        ey = y[i]
        fx = math.floor(ex / res)
        fy = math.floor(ey / res)
        inside = fx >= 0.0 and fx < w and fy >= 0.0 and fy < h
        d_end = dist[int(fy), int(fx)] if inside else max_dist
        end_dist[i] = d_end
        if abs(d_end - half) <= inlier_m:
            out[i] = 1
            continue
        if not (inside and free[int(fy), int(fx)]):
            continue
        dx = ex - lx
        dy = ey - ly
        length = math.sqrt(dx * dx + dy * dy)
        if length <= 0.0:
            continue
        ux = dx / length
        uy = dy / length
        stop = length - inlier_m - res
        t = 0.0
        crossed = False
        while t < stop:
            px = lx + ux * t
            py = ly + uy * t
            cx = math.floor(px / res)
            cy = math.floor(py / res)
            if not (cx >= 0.0 and cx < w and cy >= 0.0 and cy < h):
                crossed = True
                break
            d = dist[int(cy), int(cx)]
            if d < half:
                crossed = True
                break
            t += max(d - 3.0 * half, half)
        if not crossed:
            out[i] = 2

def _warm() -> None:  # pragma: no cover - exercised by curio warmup
    """Compile every kernel of this module once (tiny inputs)."""
    d = np.zeros((3, 3))
    v = np.zeros(1)
    lookup_points(d, 0.0, 0.0, 0.05, 2.0, v, v, np.zeros(1))
    lookup_poses(d, 0.0, 0.0, 0.05, 2.0, v, v, v, v, v, v, np.zeros((1, 1)))
    lookup_grad_points(d, 0.0, 0.0, 0.05, 2.0, v, v, np.zeros(1), np.zeros(1), np.zeros(1))
    match_terms(d, 0.0, 0.0, 0.05, 2.0, 0.0, 0.0, 1.0, 0.0, v, v, 0.025, 0.15, 0.05,
                np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    heaviest_bin(np.zeros((1, 3)), v, 0.5, np.zeros(1, dtype=np.bool_))
    ends_local(0.0, 0.0, 1.0, 0.0, np.zeros((1, 2)), 0.0, 0.0, np.zeros(1), np.zeros(1))
    beam_evidence(d, np.ones((3, 3), dtype=np.bool_), 0.05, 2.0, 0.0, 0.0, v, v, 0.12,
                  np.zeros(1, dtype=np.int8), np.zeros(1))
