"""Navigation wiring: costmap, planner, controller, navigator, recovery, obstacles, safety.

``build_navigation(app)`` constructs the navigation parts from ``app.cfg`` and registers them
on ``app`` (``app.costmap``, ``app.planner``, ``app.controller``, ``app.navigator``,
``app.obstacles``, ``app.blocked``, ``app.safety``):

* the costmap is built on the navigation map: ``app.map_server.grid`` when the estimation
  wiring set one, else the map file ``sim.world``; a :class:`~curio.nav.costmap.CostmapNode`
  keeps it up to date from ``/scan`` and ``/pose`` and follows ``/map``;
* the navigator (``curio.nav.navigator``) plans in a worker thread on the real clock and
  inline on a simulated clock (so simulated runs are deterministic);
* the navigator compiles the planner's kernels (``GlobalPlanner.warm_up``) when it starts, off
  the loop on the real clock, and the controller gets the costmap's cost scaling;
* the safety stage is always built: it is the only publisher of ``/cmd_vel``.

The rover's pose comes from ``/pose`` (``map``), published by the estimation wiring.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from curio.core.clock import SimClock
from curio.safety.stage import register_safety

if TYPE_CHECKING:
    from curio.app import App

__all__ = ["build_navigation"]


def build_navigation(app: App) -> None:
    """Construct this subsystem's parts from ``app.cfg`` and register them on ``app``."""
    from curio.app import Part
    from curio.estimation.maps import load_map
    from curio.nav.controller import LocalController
    from curio.nav.costmap import Costmap, CostmapNode
    from curio.nav.navigator import NavigatorNode
    from curio.nav.obstacles import register_obstacles
    from curio.nav.planner import GlobalPlanner, narrow_cost
    from curio.nav.recovery import Recovery

    cfg = app.cfg
    register_safety(app)
    grid = getattr(app.map_server, "grid", None)
    if grid is None:
        grid = load_map(cfg.resolve(cfg.sim.world))
    costmap = Costmap(grid, cfg.robot, cfg.nav.costmap)
    node = CostmapNode(costmap, app.bus, app.clock, cfg.nav.costmap)
    app.costmap = costmap
    app.add(Part("costmap", run=node.run))
    planner = GlobalPlanner(cfg.nav.planner, narrow_cost=narrow_cost(
        costmap.inscribed_radius_m, costmap.circumscribed_radius_m,
        cfg.nav.costmap.cost_scaling_factor))
    app.planner = planner
    controller = LocalController(cfg.nav.controller, cfg.robot, costmap)
    controller.set_cost_scaling(cfg.nav.costmap.cost_scaling_factor)
    app.controller = controller
    recovery = Recovery(cfg.nav.recovery, cfg.robot, app.clock, app.bus, costmap)
    navigator = NavigatorNode(cfg, app.clock, app.bus, costmap, planner, controller, recovery,
                              plan_in_thread=not isinstance(app.clock, SimClock))
    app.navigator = navigator
    app.add(Part("navigator", run=navigator.run, close=navigator.close))
    register_obstacles(app)
