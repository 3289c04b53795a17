"""Scenario ``tour``: drive paths 1 and 2 of ``bt.paths``, then home, through the navigator.

Each waypoint is sent as one goal (with its heading when the path gives ``yaw_deg``), in the
order path 1, path 2, path 0 (home), the way the original's path follower drove them. A
waypoint that fails (ABORTED or REJECTED) is recorded and the tour goes on with the next one.

Success: every waypoint reached (navigator SUCCEEDED and the true position within
``xy_goal_tolerance_m`` + 0.1 m) and no collision. ``goals_total`` = number of waypoints.

Metrics: ``waypoints`` (``[{path, index, state, time_s, error_m, error}]``), ``tour_time_s``.
"""

from __future__ import annotations

import math
from typing import Any

from curio.core.config import Config, PathConfig
from curio.core.geometry import Pose2D
from curio.nav.api import GoalHandle, GoalState
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed

__all__ = ["TourScenario", "path_poses"]


def path_poses(path: PathConfig) -> list[Pose2D]:
    """The waypoints of a configured path as poses in ``map`` (NaN yaw when none is given)."""
    out = []
    for k, (x, y) in enumerate(path.points):
        yaw = math.nan
        if path.yaw_deg is not None and k < len(path.yaw_deg):
            yaw = math.radians(path.yaw_deg[k])
        out.append(Pose2D(float(x), float(y), yaw))
    return out


class TourScenario(Scenario):
    """Paths 1 and 2, then home."""

    name = "tour"
    description = "drive paths 1 and 2 of bt.paths, then home, through the navigator"
    default_duration_s = 900.0
    order = (1, 2, 0)

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """Check that the configured paths exist."""
        missing = [i for i in self.order if i >= len(cfg.bt.paths)]
        if missing:
            raise ScenarioFailed(f"bt.paths has {len(cfg.bt.paths)} paths; the tour needs paths "
                                 f"{', '.join(map(str, self.order))}")
        return cfg

    async def run(self, ctx: ScenarioContext) -> None:
        """Drive every waypoint in order."""
        nav = await ctx.navigator_ready()
        plan = [(pid, k, pose) for pid in self.order
                for k, pose in enumerate(path_poses(ctx.cfg.bt.paths[pid]))]
        ctx.goals_total = len(plan)
        tol = ctx.cfg.nav.controller.xy_goal_tolerance_m + 0.1
        results: list[dict[str, Any]] = []
        t_start = ctx.now()
        budget_total = (ctx.args.duration_s or self.default_duration_s) - 2.0
        for pid, k, pose in plan:
            t0 = ctx.now()
            handle = nav.send_goal(pose, tag=f"path {pid} wp {k + 1}")
            left = max(1.0, budget_total - (ctx.now() - t_start))

            def finished(h: GoalHandle = handle) -> bool:
                return h.done

            await ctx.wait_until(finished, min(300.0, left), 0.1)
            if not handle.done:
                nav.cancel("waypoint time is up")
            await ctx.sleep(0.2)
            truth = ctx.truth()
            err = truth.distance_to(pose) if truth is not None else math.inf
            ok = handle.state is GoalState.SUCCEEDED and err <= tol
            if ok:
                ctx.goals_reached += 1
            results.append({"path": pid, "index": k, "state": handle.state.value,
                            "time_s": round(ctx.now() - t0, 2),
                            "error_m": round(err, 3) if math.isfinite(err) else None,
                            "error": str(handle.error) if handle.error else None})
            ctx.record("tour.waypoint", path=pid, index=k, ok=ok, state=handle.state.value)
        ctx.metrics["waypoints"] = results
        ctx.metrics["tour_time_s"] = round(ctx.now() - t_start, 2)
        ctx.check("all_waypoints", ctx.goals_reached == ctx.goals_total,
                  f"{ctx.goals_reached}/{ctx.goals_total} waypoints reached")
        ctx.check("no_collision", not ctx.events_of("collision"),
                  f"{len(ctx.events_of('collision'))} collision events")
