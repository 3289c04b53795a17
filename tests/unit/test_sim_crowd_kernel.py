"""The crowd step's compiled per-visitor arithmetic (``crowd_inputs``, ``crowd_advance``) gives
the same bits as the numpy expressions it replaced."""

from __future__ import annotations

import numpy as np

from curio.sim.crowd_kernel import crowd_advance, crowd_inputs
from curio.sim.walkmap import WalkMap
from tests.unit.test_controller import open_grid

F64 = np.ndarray


def _walk() -> WalkMap:
    grid = open_grid(6.0)
    grid.data[40:60, 50:55] = 100  # a pillar: walls nearer than the room's
    return WalkMap(grid, walk_clearance_m=0.3)


def _walls(walk: WalkMap, xy: F64) -> F64:
    """The wall lookup the crowd used (``WalkMap.walls``, compiled ``grid_lookup``), in numpy:
    nearest blocked cell's centre and clearance; outside the grid the point itself and 0."""
    col = np.floor((xy[:, 0] - walk.ox) / walk.res_fine).astype(np.int64)
    row = np.floor((xy[:, 1] - walk.oy) / walk.res_fine).astype(np.int64)
    h, w = walk.clearance_fine.shape
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    r, c = np.where(inside, row, 0), np.where(inside, col, 0)
    return np.column_stack([
        np.where(inside, walk.ox + (walk.near_col[r, c] + 0.5) * walk.res_fine, xy[:, 0]),
        np.where(inside, walk.oy + (walk.near_row[r, c] + 0.5) * walk.res_fine, xy[:, 1]),
        np.where(inside, walk.clearance_fine[r, c], 0.0)])


def _same(a: F64, b: F64) -> bool:
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_crowd_inputs_match_numpy() -> None:
    walk = _walk()
    rng = np.random.default_rng(3)
    n = 64
    pos = rng.uniform(-3.4, 3.4, (n, 2))  # some outside the grid
    steer = pos + rng.normal(0.0, 1.0, (n, 2))
    steer[:6] = pos[:6] + rng.uniform(-0.03, 0.03, (6, 2))  # within 0.05 m: stand
    steer[6] = pos[6]
    speed = rng.uniform(0.0, 1.4, n)
    notice = np.where(rng.uniform(size=n) < 0.3, 1.5, np.inf)
    attention = rng.uniform(0.5, 1.0, n)
    rx, ry = 0.3, -0.2
    desired, walls, here_clear, weight = (np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(n),
                                          np.zeros(n))
    crowd_inputs(pos, steer, speed, rx, ry, notice, attention, walk.clearance_fine,
                 walk.near_row, walk.near_col, walk.ox, walk.oy, walk.res_fine, desired, walls,
                 here_clear, weight)
    # The numpy code this replaced (Crowd._update, Crowd._perceive).
    to = steer - pos
    dist = np.maximum(np.hypot(to[:, 0], to[:, 1]), 1e-9)
    ref_desired = to * (np.where(dist > 0.05, speed, 0.0) / dist)[:, None]
    here = _walls(walk, pos)
    ref_walls = np.column_stack([here[:, :2], np.hypot(*(pos - here[:, :2]).T)
                                 - 0.5 * walk.res_fine])
    d = np.hypot(pos[:, 0] - rx, pos[:, 1] - ry)
    ref_weight = np.where(d <= notice, attention, 0.0)
    assert (here[:, 2] == 0.0).any() and (here[:, 2] > 0.0).any()
    assert (ref_weight == 0.0).any() and (ref_weight > 0.0).any()
    assert _same(desired, ref_desired)
    assert _same(walls, ref_walls)
    assert _same(here_clear, here[:, 2])
    assert _same(weight, ref_weight)


def test_crowd_advance_matches_numpy() -> None:
    walk = _walk()
    rng = np.random.default_rng(5)
    n = 200
    pos = rng.uniform(-2.9, 2.9, (n, 2))
    vel = rng.normal(0.0, 0.8, (n, 2))
    vel[:3] = 0.0
    acc = rng.normal(0.0, 20.0, (n, 2))  # large: some steps reach walls, some speeds capped
    acc[:2] = 0.0
    cap = rng.uniform(0.6, 1.8, n)
    dt, radius = 0.05, 0.25
    here_clear = _walls(walk, pos)[:, 2]
    rx, ry = 0.1, 0.4
    new, new_vel, near = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n, dtype=np.bool_)
    crowd_advance(pos, vel, acc, dt, cap, here_clear, 0.8 * radius, walk.clearance_fine,
                  walk.near_row, walk.near_col, walk.ox, walk.oy, walk.res_fine, rx, ry,
                  0.5 + radius + 0.2, new, new_vel, near)
    # The numpy code this replaced (Crowd._update, Crowd._rover_contacts).
    ref_vel = vel + acc * dt
    speed = np.hypot(ref_vel[:, 0], ref_vel[:, 1])
    ref_vel *= np.minimum(1.0, cap / np.maximum(speed, 1e-9))[:, None]
    ref_new = pos + ref_vel * dt
    clear_new = _walls(walk, ref_new)[:, 2]
    blocked = (clear_new < 0.8 * radius) & (clear_new < here_clear)
    ref_new[blocked] = pos[blocked]
    ref_vel[blocked] = 0.0
    ref_near = np.hypot(ref_new[:, 0] - rx, ref_new[:, 1] - ry) < 0.5 + radius + 0.2
    assert blocked.any() and not blocked.all()
    assert (speed > cap).any() and (speed < cap).any()
    assert ref_near.any() and not ref_near.all()
    assert _same(new, ref_new)
    assert _same(new_vel, ref_vel)
    assert _same(near, ref_near)
