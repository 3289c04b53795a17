"""Navigation wiring: costmap, planner, controller, recovery, navigator, obstacles.

``build_navigation`` constructs the navigation parts on the navigation map (the estimation
wiring's map server grid) and registers them:

* a :class:`~curio.nav.costmap.CostmapNode` keeps the costmap up to date from ``/scan`` and
  ``/pose`` and follows ``/map``;
* the navigator (``curio.nav.navigator``) plans through ``Clock.offload`` (a worker thread on
  the real clock, inline on a simulated one) and compiles the planner's kernels when it starts;
* the obstacle extractor and blocked-path detector judge the navigator's active goal.

The safety stage is wired separately (``curio/safety/wiring.py``); the rover's pose comes from
``/pose`` (``map``), published by the estimation wiring.
"""

from __future__ import annotations

from dataclasses import dataclass

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.parts import Part, Parts
from curio.estimation.maps import OccupancyGrid
from curio.nav.controller import LocalController
from curio.nav.costmap import Costmap, CostmapNode
from curio.nav.navigator import NavigatorNode
from curio.nav.obstacles import ObstacleNode
from curio.nav.planner import GlobalPlanner, narrow_cost
from curio.nav.recovery import Recovery
from curio.robot import RobotModel

__all__ = ["Navigation", "build_navigation"]


@dataclass(frozen=True)
class Navigation:
    """The navigation subsystem's objects (the behaviour tree and the dashboard use them)."""

    costmap: Costmap
    planner: GlobalPlanner
    controller: LocalController
    recovery: Recovery
    navigator: NavigatorNode
    obstacles: ObstacleNode
    costmap_node: CostmapNode | None = None


def build_navigation(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
                     grid: OccupancyGrid) -> Navigation:
    """Construct the navigation parts on ``grid`` (``map``) and register them on ``parts``."""
    costmap = Costmap(grid, robot, cfg.nav.costmap)
    costmap_node = CostmapNode(costmap, bus, clock, cfg.nav.costmap)
    parts.add(Part("costmap", run=costmap_node.run))
    planner = GlobalPlanner(cfg.nav.planner, narrow_cost=narrow_cost(
        costmap.inscribed_radius_m, costmap.circumscribed_radius_m,
        costmap.cost_scaling_factor))
    controller = LocalController(cfg.nav.controller, robot, costmap)
    recovery = Recovery(cfg.nav.recovery, robot, clock, bus, costmap)
    navigator = NavigatorNode(cfg, clock, bus, costmap, planner, controller, recovery)
    parts.add(Part("navigator", run=navigator.run, close=navigator.close))

    def goal_active() -> bool:
        # Holding for another rover (navigator.holds) is waiting, not being blocked.
        return navigator.active is not None and navigator.held_by is None

    obstacles = ObstacleNode(cfg.nav.blocked, robot, clock, bus, goal_active)
    parts.add(Part("obstacles", run=obstacles.run))
    return Navigation(costmap, planner, controller, recovery, navigator, obstacles,
                      costmap_node)
