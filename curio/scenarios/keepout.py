"""Scenario ``keepout``: a keep-out zone across the shortest route; the rover takes the long way.

On the default building (``maps/curio_building``) the rover starts in the lobby at ``START``
(5, 2) and is sent to the gallery at ``GOAL`` (11, 2): the short way is the gallery door
(x = 8, 6 m). An operator draws, through the zone service (as the dashboard does), a keep-out
zone over that door (``KEEPOUT``) and a speed zone of 0.12 m/s over the corridor
(``SPEED``), which the long way — through the lobby's archway, the corridor and the gallery's
north doorway, about 20 m — must cross. Then it drives back the long way to ``BACK`` (6.4, 0)
in the lobby, facing the zone a quarter of a metre from its edge. With ``--start`` and
``--goal`` the same zones are drawn and the rover drives from the start to the goal only.

The zones go through every layer: the planner (lethal cells in the costmap), the controller
(speed limit, footprint checks) and the safety stage (keep-out ahead, speed cap).

Metrics: ``zone_violations`` — control cycles (10 Hz, ``nav.controller.rate_hz``) in which
the rover's ground-truth footprint overlaps a keep-out zone (must be 0);
``speed_zone_violations`` — cycles in which the true footprint overlaps a speed zone while the
true speed exceeds the zone's limit by more than ``SPEED_TOLERANCE_MPS``; ``max_speed_in_zone_mps``,
``cycles_in_speed_zone``, ``route_length_m`` (driven) against ``straight_m``.
Success: goal reached, no zone violation, no speed-zone violation, the long way taken (driven
path at least 1.5× the straight line), no collision.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.nav.api import GoalState
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed
from curio.zones.geometry import polygon_distance, polygons_overlap

__all__ = ["KeepoutScenario"]

START = (5.0, 2.0, 0.0)
GOAL = (11.0, 2.0, 0.0)
BACK = (6.4, 0.0, 0.0)  # back in the lobby, facing the zone, 0.27 m from its edge
KEEPOUT = [[7.0, 0.2], [9.2, 0.2], [9.2, 3.8], [7.0, 3.8]]       # over the gallery door
SPEED = [[6.2, 7.2], [11.8, 7.2], [11.8, 9.45], [6.2, 9.45]]      # the corridor
SPEED_LIMIT_MPS = 0.12
SPEED_TOLERANCE_MPS = 0.005


class KeepoutScenario(Scenario):
    """A keep-out zone over the short way, a speed zone on the long way."""

    name = "keepout"
    description = "a keep-out zone across the shortest route: the rover takes the long way"
    default_duration_s = 400.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """Start in the lobby unless ``--start`` says otherwise; no tree autostart."""
        if args.start is None:
            cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"start": START})})
        bt = cfg.bt.model_copy(update={"autostart_path": None, "speak": False})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: ScenarioContext) -> None:
        """Draw the zones, drive, count the cycles in a zone."""
        zones = ctx.app.zones
        if zones is None:
            raise ScenarioFailed("zones are off (zones.enabled = false)")
        zones.add({"name": "Gallery door", "kind": "keepout", "polygon": KEEPOUT},
                  actor="scenario")
        zones.add({"name": "Corridor", "kind": "speed", "polygon": SPEED,
                   "speed_limit_mps": SPEED_LIMIT_MPS}, actor="scenario")
        goal_xy = ctx.args.goal or GOAL
        goal = Pose2D(goal_xy[0], goal_xy[1], goal_xy[2] if goal_xy[2] is not None else math.nan)
        nav = await ctx.navigator_ready(30.0)
        start = ctx.truth() or Pose2D()
        counts: dict[str, Any] = {"keepout": 0, "speed": 0, "in_speed": 0, "max_v": 0.0,
                                  "driven": 0.0, "last": start, "clearance": math.inf}
        keep = [np.asarray(KEEPOUT, dtype=np.float64)]
        slow = [np.asarray(SPEED, dtype=np.float64)]
        legs = [goal] if ctx.args.goal else [goal, Pose2D(*BACK)]
        ctx.goals_total = len(legs)
        period = 1.0 / ctx.cfg.nav.controller.rate_hz
        deadline = ctx.now() + (ctx.args.duration_s or self.default_duration_s) - 5.0
        states = []
        for leg in legs:
            handle = nav.send_goal(leg, tag="keepout goal")
            while not handle.done and ctx.now() < deadline:
                self._sample(ctx, keep, slow, counts)
                await ctx.sleep(period)
            states.append(handle.state.value if handle.done else "timed out")
            ctx.goals_reached += int(handle.state is GoalState.SUCCEEDED)
        ok = ctx.goals_reached == ctx.goals_total
        straight = start.distance_to(goal)
        ctx.metrics.update({
            "zone_violations": counts["keepout"],
            "speed_zone_violations": counts["speed"],
            "cycles_in_speed_zone": counts["in_speed"],
            "max_speed_in_zone_mps": round(counts["max_v"], 4),
            "speed_limit_mps": SPEED_LIMIT_MPS,
            "straight_m": round(straight, 3),
            "driven_m": round(counts["driven"], 3),
            "min_keepout_clearance_m": round(counts["clearance"], 4),
            "goal_states": states,
        })
        ctx.check("every goal reached", ok, str(states))
        ctx.check("never inside the keep-out zone", counts["keepout"] == 0,
                  f"{counts['keepout']} cycles")
        ctx.check("never faster than the speed zone allows", counts["speed"] == 0,
                  f"{counts['speed']} cycles, max {counts['max_v']:.3f} m/s")
        ctx.check("took the long way", counts["driven"] >= 1.5 * straight,
                  f"drove {counts['driven']:.1f} m, straight line {straight:.1f} m")
        ctx.check("no collision", not ctx.events_of("collision"))

    @staticmethod
    def _sample(ctx: ScenarioContext, keep: list[Any], slow: list[Any],
                counts: dict[str, Any]) -> None:
        world = ctx.world
        truth = world.truth_pose
        counts["driven"] += truth.distance_to(counts["last"])
        counts["last"] = truth
        fp = truth.transform_points(np.asarray(world.footprint, dtype=np.float64))
        if any(polygons_overlap(fp, z) for z in keep):
            counts["keepout"] += 1
        counts["clearance"] = min(counts["clearance"],
                                  *(polygon_distance(fp, z) for z in keep))
        if any(polygons_overlap(fp, z) for z in slow):
            v = abs(world.truth_twist[0])
            counts["in_speed"] += 1
            counts["max_v"] = max(counts["max_v"], v)
            if v > SPEED_LIMIT_MPS + SPEED_TOLERANCE_MPS:
                counts["speed"] += 1
