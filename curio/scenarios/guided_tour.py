"""The ``guided-tour`` scenario: the tour guide takes visitors round every stop, then goes home.

The tour tree (``bt.tree = "tour"``) with the configured stops (``bt.tour_stops``; the shipped
``config.toml`` has the building's five) is started as the dashboard's Start tour button does.
Checks: every stop announced with its visitor message in order, the tour finished, the rover
back home within the goal tolerance, no collision. It is also the subject of
``curio bench stack`` (the whole application's real-time factor).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event
from curio.core.topics import EVENTS
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed

__all__ = ["GuidedTourScenario"]


class GuidedTourScenario(Scenario):
    """One guided tour of the configured stops, then home."""

    name = "guided-tour"
    description = "the tour guide visits every configured stop, then goes home"
    default_duration_s = 1800.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """The tour tree, no speech, no loop; paths in a scratch file."""
        if not cfg.bt.tour_stops:
            raise ScenarioFailed("guided-tour needs bt.tour_stops (the shipped config.toml "
                                 "has the building's tour)")
        self._tmp = tempfile.mkdtemp(prefix="curio-guided-tour-")
        bt = cfg.bt.model_copy(update={"tree": "tour", "autostart_path": None, "speak": False,
                                       "tour_loop": False,
                                       "paths_file": str(Path(self._tmp) / "paths.json")})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: ScenarioContext) -> None:
        """Start the tour, wait for it to finish, send the rover home."""
        stops = ctx.cfg.bt.tour_stops
        ctx.goals_total = len(stops) + 1
        sub = ctx.bus.subscribe(EVENTS)
        events: list[Event] = []

        def seen(kind: str) -> list[Event]:
            events.extend(sub.drain())
            return [e for e in events if e.kind == kind]

        try:
            ctx.press("start_tour")
            finished = await ctx.wait_until(
                lambda: any(e.detail.get("path_id") == -1 for e in seen("path.finished"))
                or bool(seen("waypoint.failed")), 1500.0, poll_s=0.2)
            announced = [e.detail.get("name") for e in seen("tour.stop")]
            ctx.goals_reached = len(announced)
            if not finished or seen("waypoint.failed"):
                raise ScenarioFailed(f"the tour did not finish; stops announced: {announced}")
            ctx.check("every stop announced in order", announced == [s.name for s in stops],
                      str(announced))
            ctx.check("visitor messages shown",
                      [e.detail.get("message") for e in seen("tour.stop")]
                      == [s.message for s in stops])
            ctx.press("go_home")
            home = ctx.app.robot.home
            tolerance_m = ctx.cfg.nav.controller.xy_goal_tolerance_m + 0.05

            def at_home() -> bool:
                truth = ctx.truth()
                return truth is not None and truth.distance_to(home) <= tolerance_m

            back = await ctx.wait_until(at_home, 300.0, poll_s=0.2)
            if back:
                ctx.goals_reached += 1
            truth = ctx.truth() or Pose2D()
            ctx.check("back home", back, f"{truth.distance_to(home):.3f} m from home")
        finally:
            sub.close()
