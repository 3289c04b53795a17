"""Scenario ``goto``: drive to one goal on any map through the navigator.

``curio sim goto [--map YAML] [--start X,Y,YAW] [--goal X,Y[,YAW]] [--seed N]``

* Without ``--start`` the rover starts at ``sim.start`` / ``robot.home``; when that pose is not
  free on the chosen map, at a free pose drawn from the seed.
* Without ``--goal`` a free goal at least 3 m away (straight line) is drawn from the seed.
* A goal without a heading has no yaw requirement.

Success: the navigator reports SUCCEEDED, the rover's *true* position (simulator ground truth)
is within ``nav.controller.xy_goal_tolerance_m`` + 0.1 m (localisation error allowance) of the
goal — and, when the goal has a heading, its true heading within ``yaw_goal_tolerance_rad`` +
0.1 rad — and no collision happened. ``goals_total`` = 1.

Metrics: ``goal`` / ``start``, ``nav_time_s`` (goal accepted → done), ``plan_length_m`` (the
first global plan), ``ideal_time_s`` = plan length / ``nav.controller.max_speed_mps``,
``time_ratio`` = nav time / ideal time, ``final_error_m``, ``final_state``, ``error_code``,
``recoveries``, ``replans``, ``final_yaw_error_rad`` (goals with a heading).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.topics import PLAN, POSE
from curio.nav.api import GoalState
from curio.nav.costs import INSCRIBED, cost_at_distance
from curio.nav.planner import path_length_m
from curio.robot import RobotModel
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed

__all__ = ["GotoScenario", "free_poses", "pick_free_pose"]


def free_poses(cfg: Config, clearance_m: float = 0.15) -> tuple[np.ndarray, Any]:
    """Cell centres (``(N, 2)``, map) where the rover fits with some clearance, and the costmap.

    Uses the navigation costmap of ``sim.world`` (its inflation), so a pose listed here can be
    planned to: the centre cost is below the inscribed cost by a margin.
    """
    from curio.estimation.maps import load_map
    from curio.nav.costmap import Costmap

    grid = load_map(cfg.resolve(cfg.sim.world))
    cm = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    costs = cm.costs()
    limit = cost_at_distance(clearance_m, cfg.nav.costmap.cost_scaling_factor)
    ok = (costs < limit) & (grid.free_mask())
    rows, cols = np.nonzero(ok)
    xs = grid.origin.x + (cols + 0.5) * grid.resolution_m
    ys = grid.origin.y + (rows + 0.5) * grid.resolution_m
    return np.stack([xs, ys], axis=1), cm


def pick_free_pose(cfg: Config, rng: np.random.Generator, away_from: Pose2D | None = None,
                   min_distance_m: float = 3.0, clearance_m: float = 0.15) -> Pose2D:
    """A random free pose (yaw random) at least ``min_distance_m`` from ``away_from``."""
    pts, cm = free_poses(cfg, clearance_m)
    if len(pts) == 0:
        raise ScenarioFailed(f"the map {cfg.sim.world} has no cell where the rover fits")
    if away_from is not None:
        far = np.hypot(pts[:, 0] - away_from.x, pts[:, 1] - away_from.y) >= min_distance_m
        if far.any():
            pts = pts[far]
    for _ in range(200):
        x, y = pts[int(rng.integers(len(pts)))]
        yaw = float(rng.uniform(-math.pi, math.pi))
        if cm.footprint_cost(Pose2D(float(x), float(y), yaw)) < INSCRIBED:
            return Pose2D(float(x), float(y), yaw)
    x, y = pts[int(rng.integers(len(pts)))]
    return Pose2D(float(x), float(y), 0.0)


class GotoScenario(Scenario):
    """One goal on any map, through the navigator."""

    name = "goto"
    description = "drive to one goal (--goal X,Y[,YAW]) on any map (--map) from --start"
    default_duration_s = 600.0

    def __init__(self) -> None:
        self.goal: Pose2D | None = None

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """Choose a free start (if the given one is not) and the goal."""
        rng = np.random.default_rng([cfg.sim.seed, 0x60])
        sim = cfg.sim.model_copy()
        start = Pose2D(*(sim.start if sim.start is not None else cfg.robot.home))
        if args.start is None:
            from curio.estimation.maps import load_map
            from curio.nav.costmap import Costmap

            grid = load_map(cfg.resolve(sim.world))
            cm = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
            r, c = cm.world_to_cell(start.x, start.y)
            if not cm.in_bounds(r, c) or cm.footprint_cost(start) >= INSCRIBED:
                start = pick_free_pose(cfg, rng)
                sim.start = start.as_tuple()
        if args.goal is not None:
            gx, gy, gyaw = args.goal
            self.goal = Pose2D(gx, gy, math.nan if gyaw is None else gyaw)
        else:
            g = pick_free_pose(cfg.model_copy(update={"sim": sim}), rng, start, 3.0)
            self.goal = Pose2D(g.x, g.y, math.nan)
        return cfg.model_copy(update={"sim": sim})

    async def run(self, ctx: ScenarioContext) -> None:
        """Send the goal, wait for the outcome, check it against the truth."""
        goal = self.goal
        if goal is None:
            raise ScenarioFailed("goto needs a goal (--goal X,Y[,YAW])")
        nav = await ctx.navigator_ready()
        start = ctx.truth() or ctx.bus.latest(POSE).pose  # type: ignore[union-attr]
        ctx.goals_total = 1
        ctx.metrics["start"] = [round(start.x, 3), round(start.y, 3), round(start.yaw, 3)]
        ctx.metrics["goal"] = [round(goal.x, 3), round(goal.y, 3),
                               None if math.isnan(goal.yaw) else round(goal.yaw, 3)]
        t0 = ctx.now()
        plans_before = getattr(nav, "plan_count", 0)
        handle = nav.send_goal(goal, tag="goto")
        first_plan: list[Pose2D] = []

        def done_or_planned() -> bool:
            plan = ctx.bus.latest(PLAN)
            if not first_plan and plan is not None and len(plan.poses) > 1 and \
                    handle.state is GoalState.ACTIVE:
                first_plan.extend(plan.poses)
            return bool(handle.done)

        budget = max(1.0, (ctx.args.duration_s or self.default_duration_s) - ctx.now() - 1.0)
        finished = await ctx.wait_until(done_or_planned, budget, 0.1)
        nav_time = ctx.now() - t0
        await ctx.sleep(0.3)
        truth = ctx.truth()
        final_err = truth.distance_to(goal) if truth is not None else math.inf
        plan_len = path_length_m(first_plan) if first_plan else None
        vmax = ctx.cfg.nav.controller.max_speed_mps
        ctx.metrics.update({
            "nav_time_s": round(nav_time, 3),
            "plan_length_m": None if plan_len is None else round(plan_len, 3),
            "ideal_time_s": None if plan_len is None else round(plan_len / vmax, 3),
            "time_ratio": None if not plan_len else round(nav_time / (plan_len / vmax), 4),
            "final_error_m": round(final_err, 4) if math.isfinite(final_err) else None,
            "final_state": handle.state.value,
            "error_code": handle.error.code if handle.error is not None else None,
            "error": str(handle.error) if handle.error is not None else None,
            "recoveries": handle.recoveries,
            "replans": getattr(nav, "plan_count", 0) - plans_before,
        })
        if not finished:
            nav.cancel("scenario time is up")
            duration = ctx.args.duration_s or self.default_duration_s
            raise ScenarioFailed(f"the goal was not reached within the scenario's {duration:g} s "
                                 f"(--duration; {budget:.0f} s of it left to drive)")
        tol = ctx.cfg.nav.controller.xy_goal_tolerance_m + 0.1
        reached = handle.state is GoalState.SUCCEEDED and final_err <= tol
        if math.isfinite(goal.yaw) and truth is not None:
            yaw_err = abs(math.remainder(truth.yaw - goal.yaw, 2 * math.pi))
            ctx.metrics["final_yaw_error_rad"] = round(yaw_err, 4)
            yaw_tol = ctx.cfg.nav.controller.yaw_goal_tolerance_rad + 0.1
            reached = reached and yaw_err <= yaw_tol
        if reached:
            ctx.goals_reached = 1
        ctx.check("goal_reached", reached,
                  f"state {handle.state.value}, true distance {final_err:.3f} m (<= {tol:.2f})"
                  + (f"; {handle.error}" if handle.error is not None else ""))
        self.check_collisions(ctx)

    def check_collisions(self, ctx: ScenarioContext) -> None:
        """The check on collisions: none at all (``crowd`` counts only the rover's)."""
        ctx.check("no_collision", not ctx.events_of("collision"),
                  f"{len(ctx.events_of('collision'))} collision events")
