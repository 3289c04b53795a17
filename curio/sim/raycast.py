"""Lidar ray casting against an occupancy grid and analytic shapes, all beams per call.

Static map, two backends of :class:`GridRaycaster` (same results, tested against each other):

* ``compiled`` (default): one call into a numba kernel that walks each beam through the grid
  exactly (Amanatides–Woo DDA), jumping through open space on a precomputed distance field.
  About 0.05 ms for 360 beams — what the simulator's ≥ 200× real-time target needs.
* ``numpy``: vectorised over all beams at once — sphere tracing on the same distance field,
  dense fixed-step windows for the beams that creep along a wall, and an exact slab (ray–AABB)
  refinement of each hit. About 0.3–0.6 ms for 360 beams (numpy call overhead dominates).

Dynamic objects (boxes, closed doors, people): analytic ray–segment and ray–circle intersection
over beams × shapes.

Frames and units: everything in ``map`` metres and radians; the grid may have a rotated origin.
A beam that leaves the grid or reaches ``max_range_m`` without a hit returns ``inf``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from curio.core.distance import distance_to_features
from curio.estimation.maps import OccupancyGrid
from curio.sim.raycast_kernel import cast_beams

__all__ = ["GridRaycaster", "cast_circles", "cast_segments", "naive_cast"]

F64 = npt.NDArray[np.float64]

_DENSE_SAMPLES = 48  # samples of the fixed-step window (at half a cell each)
_SPHERE_STEPS = 8  # sphere-tracing steps between dense windows
_PREPASS_STEPS = 14  # sphere-tracing steps every beam takes before any bookkeeping


class GridRaycaster:
    """Casts many rays at once into the occupied cells of a grid.

    Args:
        grid: the map; cells with ``occupied_mask()`` are obstacles, everything else (free and
            unknown) lets the beam through.
    """

    def __init__(self, grid: OccupancyGrid, backend: str = "compiled") -> None:
        if backend not in ("compiled", "numpy"):
            raise ValueError(f"ray caster backend must be 'compiled' or 'numpy', got {backend!r}")
        self.backend = backend
        self.grid = grid
        self.res = float(grid.resolution_m)
        self.occupied = np.ascontiguousarray(grid.occupied_mask())
        h, w = self.occupied.shape
        # Padded copies with a one-cell ring that reads "outside": code 0 free, 1 occupied,
        # 2 outside. The distance transform treats the ring as an obstacle too, so a safe step
        # never leaves the padded grid.
        self._h, self._w = h, w
        self._wp = w + 2
        code = np.full((h + 2, w + 2), 2, dtype=np.int8)
        code[1:-1, 1:-1] = self.occupied.astype(np.int8)
        # Distance (cells) from each cell centre to the nearest blocking cell centre, and a
        # lower bound of the distance from any point of the cell to any blocking square.
        dist_cells = distance_to_features(code != 0)
        clr_cells = np.maximum(dist_cells - math.sqrt(2.0), 0.0)
        self.clearance_m = np.ascontiguousarray(clr_cells[1:-1, 1:-1] * self.res)
        # Sphere-tracing step (cells): the clearance, at least half a cell; 0 where blocked.
        step = np.where(code == 0, np.maximum(clr_cells, 0.5), 0.0)
        self._code_flat = code.ravel()
        self._step_flat = step.ravel()
        self._clr_pad_flat = (clr_cells * self.res).ravel()
        self._clr_cells_flat = np.ascontiguousarray(clr_cells.ravel())
        self._occ_flat = self.occupied.ravel()
        self._clr_flat = self.clearance_m.ravel()
        self._inv_res = 1.0 / self.res
        self._origin = grid.origin
        self._c0, self._s0 = math.cos(grid.origin.yaw), math.sin(grid.origin.yaw)

    # -- helpers ---------------------------------------------------------------------------
    def to_grid(self, x_m: float, y_m: float, yaw_rad: float) -> tuple[float, float, float]:
        """A map pose expressed in the grid's frame (origin at cell (0, 0)'s corner)."""
        dx, dy = x_m - self._origin.x, y_m - self._origin.y
        return (self._c0 * dx + self._s0 * dy, -self._s0 * dx + self._c0 * dy,
                yaw_rad - self._origin.yaw)

    def _lookup(self, gx: F64, gy: F64) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.bool_]]:
        col = np.floor(gx / self.res).astype(np.intp)
        row = np.floor(gy / self.res).astype(np.intp)
        inside = (col >= 0) & (col < self._w) & (row >= 0) & (row < self._h)
        idx = np.where(inside, row * self._w + col, 0)
        return idx, inside

    def clearance_at(self, x_m: float, y_m: float) -> float:
        """Lower bound of the distance (m) from map point (x, y) to any occupied cell."""
        gx, gy, _ = self.to_grid(x_m, y_m, 0.0)
        col, row = math.floor(gx / self.res), math.floor(gy / self.res)
        if not (0 <= col < self._w and 0 <= row < self._h):
            return 0.0
        return float(self._clr_flat[row * self._w + col])

    def occupied_at(self, xy_m: F64) -> npt.NDArray[np.bool_]:
        """Whether each map point of an ``(N, 2)`` array lies in an occupied cell."""
        c, s = self._c0, self._s0
        dx = xy_m[:, 0] - self._origin.x
        dy = xy_m[:, 1] - self._origin.y
        idx, inside = self._lookup(c * dx + s * dy, -s * dx + c * dy)
        return inside & self._occ_flat[idx]

    # -- casting ---------------------------------------------------------------------------
    def _index(self, gx: F64, gy: F64) -> npt.NDArray[np.intp]:
        """Flat indices into the padded arrays (points outside land on the ring)."""
        fx = gx * self._inv_res + 1.0
        fy = gy * self._inv_res + 1.0
        np.maximum(fx, 0.0, out=fx)
        np.minimum(fx, self._w + 1.0, out=fx)
        np.maximum(fy, 0.0, out=fy)
        np.minimum(fy, self._h + 1.0, out=fy)
        out: npt.NDArray[np.intp] = fy.astype(np.intp) * self._wp + fx.astype(np.intp)
        return out

    def cast(self, ox_m: float, oy_m: float, angles_rad: F64, max_range_m: float) -> F64:
        """Ranges (m) from map point (ox, oy) along map-frame ``angles_rad``; ``inf`` = no hit.

        Uses the backend chosen at construction (``compiled`` or ``numpy``).
        """
        if self.backend == "numpy":
            return self.cast_numpy(ox_m, oy_m, angles_rad, max_range_m)
        return self.cast_compiled(ox_m, oy_m, angles_rad, max_range_m)

    def cast_compiled(self, ox_m: float, oy_m: float, angles_rad: F64,
                      max_range_m: float) -> F64:
        """The compiled exact traversal (``curio.sim.raycast_kernel``), all beams in one call."""
        gx0, gy0, rot = self.to_grid(ox_m, oy_m, 0.0)
        ang = np.asarray(angles_rad, dtype=np.float64) + rot
        out = np.empty(len(ang))
        x0, y0 = gx0 * self._inv_res + 1.0, gy0 * self._inv_res + 1.0
        if not (x0 >= 0.0 and y0 >= 0.0 and x0 < self._w + 2 and y0 < self._h + 2):
            out.fill(np.inf)
            return out
        cast_beams(self._code_flat, self._clr_cells_flat, self._wp, x0, y0, np.cos(ang),
                   np.sin(ang), max_range_m * self._inv_res, out)
        out *= self.res
        return out

    def cast_numpy(self, ox_m: float, oy_m: float, angles_rad: F64, max_range_m: float) -> F64:
        """The vectorised numpy caster: sphere tracing over all beams at once, dense windows
        for the beams that creep along walls, and an exact slab refinement of each hit."""
        gx0, gy0, rot = self.to_grid(ox_m, oy_m, 0.0)
        ang = angles_rad + rot
        dx, dy = np.cos(ang), np.sin(ang)
        n = len(ang)
        out = np.full(n, np.inf)
        if not (gx0 >= 0.0 and gy0 >= 0.0):
            return out
        if self._code_flat[self._index(np.array([gx0]), np.array([gy0]))[0]] == 1:
            return np.zeros(n)
        half = 0.5 * self.res
        code, clr = self._code_flat, self._clr_pad_flat
        # Pre-pass: a fixed number of sphere-tracing steps on every beam, in cell units, with
        # no bookkeeping (blocked cells have step 0, so beams stop there by themselves).
        x0, y0 = gx0 * self._inv_res + 1.0, gy0 * self._inv_res + 1.0
        wp, steps = self._wp, self._step_flat
        tc = np.zeros(n)
        for _ in range(_PREPASS_STEPS):
            idx = (y0 + tc * dy).astype(np.intp) * wp + (x0 + tc * dx).astype(np.intp)
            tc += steps[idx]
        idx = (y0 + tc * dy).astype(np.intp) * wp + (x0 + tc * dx).astype(np.intp)
        c = code[idx]
        t_all = tc * self.res
        hit_beams: list[npt.NDArray[np.intp]] = []
        hit_t: list[F64] = []
        hit0 = (c == 1) & (t_all <= max_range_m)
        if hit0.any():
            hit_beams.append(np.nonzero(hit0)[0])
            hit_t.append(t_all[hit0])
        pending = (c == 0) & (t_all <= max_range_m)
        active = np.nonzero(pending)[0]
        t = t_all[active]
        dxa, dya = dx[active], dy[active]
        window = np.arange(1, _DENSE_SAMPLES + 1, dtype=np.float64) * half
        while active.size:
            # Sphere tracing: safe steps on the clearance field, a hit on an occupied cell.
            for _ in range(_SPHERE_STEPS):
                idx = self._index(gx0 + t * dxa, gy0 + t * dya)
                c = code[idx]
                stop = (c != 0) | (t > max_range_m)
                if stop.any():
                    hit = stop & (c == 1) & (t <= max_range_m)
                    if hit.any():
                        hit_beams.append(active[hit])
                        hit_t.append(t[hit])
                    keep = ~stop
                    active, t, dxa, dya, idx = (active[keep], t[keep], dxa[keep], dya[keep],
                                                idx[keep])
                    if not active.size:
                        break
                step = clr[idx]
                small = step < half
                t = t + np.where(small, half, step)
                if np.count_nonzero(small) * 2 > small.size:
                    break
            if not active.size:
                break
            active, t, dxa, dya = self._dense_window(gx0, gy0, active, t, dxa, dya, window,
                                                     max_range_m, hit_beams, hit_t)
        if hit_beams:
            beams = np.concatenate(hit_beams)
            th = np.concatenate(hit_t)
            bx, by = dx[beams], dy[beams]
            out[beams] = self._refine(gx0, gy0, bx, by, th, gx0 + th * bx, gy0 + th * by)
        out[out > max_range_m] = np.inf
        return out

    def _dense_window(self, gx0: float, gy0: float, active: npt.NDArray[np.intp], t: F64,
                      dxa: F64, dya: F64, window: F64, max_range_m: float,
                      hit_beams: list[npt.NDArray[np.intp]], hit_t: list[F64]
                      ) -> tuple[npt.NDArray[np.intp], F64, F64, F64]:
        """Sample the next ``window`` offsets (half cells) of each active beam: beams that hit
        are appended to ``hit_beams`` / ``hit_t``, beams that stop are dropped; returns the
        beams still going, their distance (cells' metres) and directions."""
        ta = t[:, None] + window[None, :]
        c2 = self._code_flat[self._index(gx0 + ta * dxa[:, None], gy0 + ta * dya[:, None])]
        stop2 = (c2 != 0) | (ta > max_range_m)
        any_stop = stop2.any(axis=1)
        if any_stop.any():
            rows = np.nonzero(any_stop)[0]
            first = np.argmax(stop2[rows], axis=1)
            is_hit = (c2[rows, first] == 1) & (ta[rows, first] <= max_range_m)
            if is_hit.any():
                hit_beams.append(active[rows[is_hit]])
                hit_t.append(ta[rows[is_hit], first[is_hit]])
            keep = ~any_stop
            active, dxa, dya, ta = active[keep], dxa[keep], dya[keep], ta[keep]
        return active, ta[:, -1], dxa, dya

    def _refine(self, gx0: float, gy0: float, dx: F64, dy: F64, t_hit: F64, px: F64,
                py: F64) -> F64:
        """Exact entry distance of each ray into the run of occupied cells it was found in.

        The entry face of the sampled cell is found by the slab method; if the ray was already
        inside another occupied cell just before that face (it crossed a corner between two
        samples), the search repeats with that cell.
        """
        res = self.res
        t_out = t_hit.copy()
        todo = np.arange(len(t_hit))
        cx, cy = px, py
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_x = 1.0 / dx
            inv_y = 1.0 / dy
        for _ in range(4):
            cx0 = np.floor(cx / res) * res
            cy0 = np.floor(cy / res) * res
            with np.errstate(invalid="ignore"):
                tx1 = (cx0 - gx0) * inv_x[todo]
                tx2 = (cx0 + res - gx0) * inv_x[todo]
                ty1 = (cy0 - gy0) * inv_y[todo]
                ty2 = (cy0 + res - gy0) * inv_y[todo]
                tx_near = np.where(np.isfinite(tx1), np.minimum(tx1, tx2), -np.inf)
                ty_near = np.where(np.isfinite(ty1), np.minimum(ty1, ty2), -np.inf)
            t_entry = np.clip(np.maximum(tx_near, ty_near), 0.0, t_out[todo])
            t_out[todo] = t_entry
            probe = np.maximum(t_entry - 1e-7, 0.0)
            qx = gx0 + probe * dx[todo]
            qy = gy0 + probe * dy[todo]
            idx, inside = self._lookup(qx, qy)
            again = inside & self._occ_flat[idx] & (t_entry > 0.0)
            if not again.any():
                break
            todo, cx, cy = todo[again], qx[again], qy[again]
        return t_out


def cast_segments(ox_m: float, oy_m: float, dx: F64, dy: F64, segs: F64) -> F64:
    """Nearest positive hit distance of each ray against ``(S, 4)`` segments x1, y1, x2, y2."""
    n = len(dx)
    if segs.size == 0:
        return np.full(n, np.inf)
    px, py = segs[:, 0][None, :] - ox_m, segs[:, 1][None, :] - oy_m
    ex, ey = (segs[:, 2] - segs[:, 0])[None, :], (segs[:, 3] - segs[:, 1])[None, :]
    ddx, ddy = dx[:, None], dy[:, None]
    denom = ddx * ey - ddy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (px * ey - py * ex) / denom
        s = (px * ddy - py * ddx) / denom
    ok = (np.abs(denom) > 1e-12) & (t >= 0.0) & (s >= 0.0) & (s <= 1.0)
    t = np.where(ok, t, np.inf)
    return np.asarray(t.min(axis=1), dtype=np.float64)


def cast_circles(ox_m: float, oy_m: float, dx: F64, dy: F64, circles: F64) -> F64:
    """Nearest positive hit distance of each ray against ``(C, 3)`` circles x, y, radius."""
    n = len(dx)
    if circles.size == 0:
        return np.full(n, np.inf)
    cx, cy = circles[:, 0][None, :] - ox_m, circles[:, 1][None, :] - oy_m
    r = circles[:, 2][None, :]
    b = dx[:, None] * cx + dy[:, None] * cy
    c = cx * cx + cy * cy - r * r
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(c <= 0.0, 0.0, b - sq)  # origin inside a circle: range 0
    ok = (disc >= 0.0) & (t >= 0.0)
    t = np.where(ok, t, np.inf)
    return np.asarray(t.min(axis=1), dtype=np.float64)


def naive_cast(grid: OccupancyGrid, ox_m: float, oy_m: float, angles_rad: F64,
               max_range_m: float) -> F64:
    """The reference peer: one Python loop per beam, half-cell steps (for benchmarks/tests)."""
    occ = grid.occupied_mask()
    res = grid.resolution_m
    out = np.full(len(angles_rad), np.inf)
    for i, a in enumerate(angles_rad):
        ca, sa = math.cos(float(a)), math.sin(float(a))
        t = 0.0
        while t <= max_range_m:
            row, col = grid.world_to_cell(ox_m + t * ca, oy_m + t * sa)
            if not grid.in_bounds(row, col):
                break
            if occ[row, col]:
                out[i] = t
                break
            t += 0.5 * res
    return out
