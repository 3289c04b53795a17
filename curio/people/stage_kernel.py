"""Compiled distances of the people stage (numba, ``nogil``): footprint to predicted people.

For each candidate trajectory ``m``, each time step ``k`` and each person ``j``: the signed
distance (m, negative inside) from the person's predicted centre — constant velocity from
their tracked position — to the rover's footprint polygon at that pose, minus the person's
body radius. :func:`path_clearances` is the same for bodies whose future is known (another
rover's predicted path) instead of constant velocity, each with its own radius. The first call
compiles the kernel; numba caches the machine code on disk.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["path_clearances", "people_clearances"]

F64 = npt.NDArray[np.float64]


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _polygon_distance(px: float, py: float, poly: F64) -> float:  # pragma: no cover
    """Signed distance (m) from a point to a polygon's boundary (negative inside)."""
    n = poly.shape[0]
    best = math.inf
    inside = False
    for i in range(n):
        ax, ay = poly[i, 0], poly[i, 1]
        bx, by = poly[(i + 1) % n, 0], poly[(i + 1) % n, 1]
        ex, ey = bx - ax, by - ay
        ll = ex * ex + ey * ey
        u = 0.0 if ll == 0.0 else max(0.0, min(1.0, ((px - ax) * ex + (py - ay) * ey) / ll))
        dx, dy = px - ax - u * ex, py - ay - u * ey
        d = math.sqrt(dx * dx + dy * dy)
        if d < best:
            best = d
        if (ay > py) != (by > py):
            xc = ax + (py - ay) * ex / ey
            if px < xc:
                inside = not inside
    return -best if inside else best


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
                                                 footprint) - radius


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
    m_n, k_n = poses.shape[0], poses.shape[1]
    for m in range(m_n):
        for k in range(k_n):
            x, y, yaw = poses[m, k, 0], poses[m, k, 1], poses[m, k, 2]
            c, s = math.cos(yaw), math.sin(yaw)
            for j in range(futures.shape[0]):
                dx = futures[j, k, 0] - x
                dy = futures[j, k, 1] - y
                out[m, k, j] = _polygon_distance(c * dx + s * dy, -s * dx + c * dy,
                                                 footprint) - radii[j]
