"""The replanner: when the navigator asks the global planner for a new plan, and the plan jobs.

A plan is due (:meth:`Replanner.due`) when the waypoint has none yet (``new goal``), when the
plan ahead of the rover has run into a lethal or inscribed cell of the costmap for
``nav.planner.blocked_confirm_s`` without a break (``path blocked``: lidar noise next to walls
marks and clears single cells from scan to scan, and a flicker must not swap the plan for a
detour and back every second), and every ``1 / nav.planner.replan_rate_hz`` seconds
(``periodic``). Plans run through ``Clock.offload`` (a worker thread on the real clock, inline
on a simulated one); at most one at a time, and a result for another goal or waypoint is
dropped.

Where the rover got stuck, :class:`KeepOutSpots` remembers a spot ahead on its plan for
``nav.recovery.keep_out_s``; later plans treat a disc of ``keep_out_radius_m`` around it as
lethal, except where that would cut the goal off (then the plan is made without them).
Positions are in ``map``, metres; times are clock seconds.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from curio.core.clock import Clock
from curio.core.config import PlannerConfig, RecoveryConfig
from curio.core.geometry import Pose2D
from curio.nav.api import GoalHandle, NavError, NoPathError
from curio.nav.costs import INSCRIBED, LETHAL, NO_INFORMATION, CostGrid

__all__ = ["KeepOutSpots", "PlanFollower", "Planner", "Replanner"]

U8 = npt.NDArray[np.uint8]
F64 = npt.NDArray[np.float64]


class Planner(Protocol):
    """What the navigator needs from the global planner."""

    def plan(self, start: Pose2D, goal: Pose2D, costs: U8, resolution_m: float,
             origin: Pose2D) -> list[Pose2D]:
        """A path from start to goal, or a typed NavError."""
        ...


class PlanFollower(Protocol):
    """What the replanner reads of the local controller: the plan it follows ``(N, 3)`` in
    ``map`` and the index of the plan pose nearest the rover."""

    @property
    def plan(self) -> F64:
        """The plan being followed."""
        ...

    @property
    def plan_index(self) -> int:
        """The plan pose nearest the rover at the last cycle."""
        ...


class KeepOutSpots:
    """Spots where the rover got stuck, which later plans route around (module docstring).

    Args:
        cfg: ``nav.recovery`` (``keep_out_radius_m``, ``keep_out_s``).
        costmap: the grid the spots are drawn on.
    """

    def __init__(self, cfg: RecoveryConfig, costmap: CostGrid) -> None:
        self.cfg = cfg
        self.costmap = costmap
        self.spots: list[tuple[float, float, float]] = []  # (x, y, expiry clock s)

    def clear(self) -> None:
        """A new goal: no spots."""
        self.spots = []

    def add(self, follower: PlanFollower, pose: Pose2D, now_s: float,
            ahead_m: float = 0.5) -> tuple[float, float] | None:
        """Remember the spot about ``ahead_m`` along the followed plan from ``pose``; return
        it (None without a plan or with keep-out spots off)."""
        plan = follower.plan
        if len(plan) == 0 or self.cfg.keep_out_radius_m <= 0.0:
            return None
        i = follower.plan_index
        d = np.hypot(plan[i:, 0] - pose.x, plan[i:, 1] - pose.y)
        beyond = np.nonzero(d >= ahead_m)[0]
        j = i + int(beyond[0]) if len(beyond) else len(plan) - 1
        x, y = float(plan[j, 0]), float(plan[j, 1])
        self.spots.append((x, y, now_s + self.cfg.keep_out_s))
        return x, y

    def apply(self, costs: U8, start: Pose2D, goal: Pose2D, now_s: float) -> U8:
        """``costs`` with the live spots made lethal (``costs`` itself when none applies);
        spots near the start or the goal are left out, expired ones forgotten."""
        self.spots = [k for k in self.spots if k[2] > now_s]
        radius = self.cfg.keep_out_radius_m
        spots = [(x, y) for x, y, _ in self.spots
                 if math.hypot(x - start.x, y - start.y) > radius + 0.4
                 and math.hypot(x - goal.x, y - goal.y) > radius + 0.2]
        if not spots or radius <= 0.0:
            return costs
        out = costs.copy()
        n = math.ceil(radius / self.costmap.resolution_m)
        h, w = out.shape
        for x, y in spots:
            r, c = self.costmap.world_to_cell(x, y)
            rr, cc = np.mgrid[max(0, r - n):min(h, r + n + 1), max(0, c - n):min(w, c + n + 1)]
            inside = (rr - r) ** 2 + (cc - c) ** 2 <= n * n
            out[rr[inside], cc[inside]] = LETHAL
        return out


@dataclass
class _PlanJob:
    task: asyncio.Future[list[Pose2D]]
    goal_id: int
    index: int
    reason: str


def _cells(grid: CostGrid, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
           ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """``(rows, cols)`` of the cells holding the map points ``(x, y)`` (may lie outside the
    grid): ``grid.world_to_cell`` for many points at once, with the same arithmetic."""
    inv = grid.origin.inverse()
    c, s = math.cos(inv.yaw), math.sin(inv.yaw)
    lx = inv.x + c * x - s * y
    ly = inv.y + s * x + c * y
    res = grid.resolution_m
    return np.floor(ly / res).astype(np.int64), np.floor(lx / res).astype(np.int64)


class Replanner:
    """When to plan, and the plan jobs (see the module docstring).

    Args:
        cfg: ``nav.planner`` (``replan_rate_hz``, ``blocked_confirm_s``).
        clock: plans run through ``clock.offload``.
        costmap: snapshots to plan on, the blocked-path check.
        planner: the global planner.
        follower: the local controller (the plan ahead of the rover).
        keep_out: the spots plans route around.
    """

    NEW_GOAL = "new goal"
    PATH_BLOCKED = "path blocked"
    PERIODIC = "periodic"

    def __init__(self, cfg: PlannerConfig, clock: Clock, costmap: CostGrid, planner: Planner,
                 follower: PlanFollower, keep_out: KeepOutSpots) -> None:
        self.cfg = cfg
        self.clock = clock
        self.costmap = costmap
        self.planner = planner
        self.follower = follower
        self.keep_out = keep_out
        self.plan_count = 0
        self.poses: list[Pose2D] = []  # the plan taken last, for waypoint ``_index``
        self._index = -1
        self._job: _PlanJob | None = None
        self._last_plan_t = -math.inf
        self._blocked_seen_t: float | None = None  # when the plan was first seen blocked

    # --- state ------------------------------------------------------------------------------
    def reset(self) -> None:
        """A new goal: no plan, no job, no keep-out spots."""
        self.forget_plan()
        self.keep_out.clear()
        self._blocked_seen_t = None

    def forget_plan(self) -> None:
        """No plan (the next waypoint, or the goal finished); a running job is cancelled."""
        self.poses = []
        self._index = -1
        self.cancel()

    def cancel(self) -> None:
        """Cancel the running plan job, if any."""
        if self._job is not None:
            self._job.task.cancel()
            self._job = None

    def abandon(self) -> None:
        """Forget the running job without cancelling it (its result will not be taken)."""
        self._job = None

    def has_plan(self, index: int) -> bool:
        """Whether there is a plan for waypoint ``index``."""
        return self._index == index and len(self.poses) > 0

    # --- jobs -------------------------------------------------------------------------------
    def start(self, start: Pose2D, handle: GoalHandle, reason: str) -> None:
        """Plan from ``start`` to the handle's current waypoint (off the loop)."""
        goal = handle.poses[handle.current_index]
        if not math.isfinite(goal.yaw):
            # No heading wanted: the planner still needs a number for the last pose.
            goal = Pose2D(goal.x, goal.y, math.atan2(goal.y - start.y, goal.x - start.x))
        plain = self.costmap.costs()
        costs = self.keep_out.apply(plain, start, goal, self.clock.now())
        res = self.costmap.resolution_m
        origin = self.costmap.origin
        planner = self.planner

        def plan() -> list[Pose2D]:
            try:
                return planner.plan(start, goal, costs, res, origin)
            except NoPathError:
                if costs is plain:
                    raise
                # Keep-out spots are a hint to look for another way, never a reason to give
                # up: where they cut the goal off (the only door out), plan without them.
                return planner.plan(start, goal, plain, res, origin)

        task = self.clock.offload(plan)
        self.plan_count += 1
        self._job = _PlanJob(task, handle.goal_id, handle.current_index, reason)
        self._last_plan_t = self.clock.now()

    def take_result(self, handle: GoalHandle) -> list[Pose2D] | NavError | None:
        """A finished job's plan for the handle's current waypoint (now the plan), its typed
        error, or None (nothing finished, cancelled, or for another goal or waypoint)."""
        job = self._job
        if job is None or not job.task.done():
            return None
        self._job = None
        if job.goal_id != handle.goal_id or job.index != handle.current_index:
            return None
        try:
            poses = job.task.result()
        except asyncio.CancelledError:
            return None
        except NavError as exc:
            return exc
        self.poses = poses
        self._blocked_seen_t = None
        self._index = handle.current_index
        return poses

    # --- when -------------------------------------------------------------------------------
    def due(self, pose: Pose2D, now_s: float, have_plan: bool) -> str | None:
        """Why to plan now (``NEW_GOAL``, ``PATH_BLOCKED``, ``PERIODIC``), or None; never
        while a job runs."""
        if self._job is not None:
            return None
        if not have_plan:
            return self.NEW_GOAL
        if self._blocked_confirmed(pose, now_s):
            return self.PATH_BLOCKED
        hz = self.cfg.replan_rate_hz
        if hz > 0 and now_s - self._last_plan_t >= 1.0 / hz:
            return self.PERIODIC
        return None

    def _blocked_confirmed(self, pose: Pose2D, now_s: float) -> bool:
        """Whether the plan has been blocked for ``blocked_confirm_s`` without a break."""
        if not self.blocked(pose):
            self._blocked_seen_t = None
            return False
        if self._blocked_seen_t is None:
            self._blocked_seen_t = now_s
        return now_s - self._blocked_seen_t >= self.cfg.blocked_confirm_s

    def blocked(self, pose: Pose2D) -> bool:
        """Whether the followed plan ahead (about 3 m) crosses a lethal or inscribed cell."""
        plan = self.follower.plan
        if len(plan) == 0:
            return False
        i0 = self.follower.plan_index
        ahead = plan[i0:i0 + 60]
        costs = self.costmap.costs()
        rows, cols = _cells(self.costmap, ahead[:, 0], ahead[:, 1])
        h, w = costs.shape
        ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        if not ok.all():
            return True
        vals = costs[rows, cols]
        # Ignore the first few poses: the rover itself may sit in an inscribed cell.
        near = np.hypot(ahead[:, 0] - pose.x, ahead[:, 1] - pose.y) < 0.35
        return bool(((vals >= INSCRIBED) & (vals != NO_INFORMATION) & ~near).any())
