"""The ``blocked-door`` scenario: a door closes in front of the rover during a tour, and reopens.

On the default world (``maps/curio_building``) the tour guide (``bt.tree = "tour"``) takes
visitors to the configured stops (``bt.tour_stops``; without any, the building's own tour of
:data:`curio.sim.worldgen.TOUR_STOPS`, with short dwell times). On the leg towards the stop
behind ``door`` (default: the library, whose door is its only way in), when the rover is
within ``trigger_m`` of the doorway the door closes (``world.set_door(name, False)``). The
way is blocked: the rover must stop short of the door (no collision), ask for help once
(``help.requested``, status ``Needs help``), hold, and when the door reopens
(``reopen_after_s`` after the request) thank (``help.resolved`` "Thanks!") and finish the tour.

Checks: every stop announced (``tour.stop`` with its message) in order, one help request after
the door closed and its resolution after it reopened, the rover never inside the closed
doorway, the tour finished, no collision.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path
from typing import Any

from curio.core.config import Config, TourStopConfig
from curio.core.geometry import Pose2D
from curio.core.messages import Event
from curio.core.topics import EVENTS, STATUS
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed

__all__ = ["BlockedDoorScenario"]


def _building_tour() -> list[TourStopConfig]:
    from curio.sim.worldgen import TOUR_STOPS

    return [TourStopConfig(name=name, x_m=x, y_m=y, dwell_s=3.0, message=message)
            for name, x, y, message in TOUR_STOPS]


class BlockedDoorScenario(Scenario):
    """A tour; a door closes in front of the rover and reopens after a while."""

    name = "blocked-door"
    description = "a door closes in front of the rover during a tour; HELP ME; it reopens"
    default_duration_s = 1500.0
    door = "library"
    trigger_m = 2.6
    reopen_after_s = 15.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """The tour tree, no speech, the building's tour when none is configured; paths in a
        scratch file (the operator's saved paths are not touched)."""
        stops = cfg.bt.tour_stops or _building_tour()
        self._tmp = tempfile.mkdtemp(prefix="curio-blocked-door-")
        bt = cfg.bt.model_copy(update={"tree": "tour", "autostart_path": None, "speak": False,
                                       "tour_stops": stops, "tour_loop": False,
                                       "paths_file": str(Path(self._tmp) / "paths.json")})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: ScenarioContext) -> None:
        """The script."""
        events_sub = ctx.bus.subscribe(EVENTS)
        status_sub = ctx.bus.subscribe(STATUS)
        events: list[Event] = []
        statuses: list[str] = []

        def poll() -> None:
            events.extend(events_sub.drain())
            statuses.extend(s.text for s in status_sub.drain())

        def of(kind: str, **match: Any) -> list[Event]:
            poll()
            return [e for e in events if e.kind == kind
                    and all(e.detail.get(k) == v for k, v in match.items())]

        try:
            await self._script(ctx, of, statuses)
        finally:
            events_sub.close()
            status_sub.close()
            shutil.rmtree(self._tmp, ignore_errors=True)

    async def _script(self, ctx: ScenarioContext, of: Any, statuses: list[str]) -> None:
        stops = ctx.cfg.bt.tour_stops
        door = ctx.world.door(self.door)
        door_xy = ((door.a[0] + door.b[0]) / 2.0, (door.a[1] + door.b[1]) / 2.0)
        ctx.goals_total = len(stops)
        ctx.press("start_tour")

        def near_door() -> bool:
            truth = ctx.truth()
            return truth is not None and math.hypot(truth.x - door_xy[0],
                                                    truth.y - door_xy[1]) < self.trigger_m

        def tour_over() -> bool:
            return bool(of("path.finished", path_id=-1)) or bool(of("waypoint.failed"))

        # Drive the tour until the rover comes near the door (or the tour ends without it).
        if not await ctx.wait_until(lambda: near_door() or tour_over(), 1200.0, poll_s=0.2):
            raise ScenarioFailed(f"the rover never came within {self.trigger_m} m of the "
                                 f"{self.door} door; statuses: {statuses[-5:]}")
        if tour_over():
            raise ScenarioFailed(f"the tour ended before reaching the {self.door} door: "
                                 f"{[e.detail for e in of('waypoint.failed')]}")
        stops_before = len(of("tour.stop"))
        ctx.world.set_door(self.door, False)
        closed_at = ctx.now()
        ctx.record("script", action="door closed", door=self.door)

        # Watch that the rover never enters the closed doorway while waiting for help.
        intrusions = 0

        def request_seen() -> bool:
            nonlocal intrusions
            truth = ctx.truth()
            if truth is not None and math.hypot(truth.x - door_xy[0],
                                                truth.y - door_xy[1]) < 0.45:
                intrusions += 1
            return bool(of("help.requested"))

        if not await ctx.wait_until(request_seen, 240.0, poll_s=0.2):
            raise ScenarioFailed(f"no help request after the {self.door} door closed; "
                                 f"statuses: {statuses[-6:]}")
        requested = of("help.requested")[0]
        ctx.check("help requested after the door closed", requested.stamp >= closed_at,
                  f"at {requested.stamp:.1f} s, door closed at {closed_at:.1f} s")
        ctx.check("status Needs help", "Needs help" in statuses, str(statuses[-4:]))
        held_from = ctx.truth() or Pose2D()
        await ctx.sleep(self.reopen_after_s)
        held_to = ctx.truth() or Pose2D()
        ctx.check("holds while asking for help", held_from.distance_to(held_to) < 0.1,
                  f"moved {held_from.distance_to(held_to):.3f} m")
        ctx.check("no thanks while the door is closed", not of("help.resolved"),
                  str([e.detail for e in of("help.resolved")]))
        ctx.world.set_door(self.door, True)
        opened_at = ctx.now()
        ctx.record("script", action="door opened", door=self.door)

        if not await ctx.wait_until(lambda: bool(of("help.resolved")), 120.0):
            raise ScenarioFailed("the help request was not resolved after the door reopened")
        resolved = of("help.resolved")[0]
        ctx.check("Thanks! after the door reopened", resolved.stamp >= opened_at
                  and resolved.detail.get("message") == "Thanks!", str(resolved.detail))
        if not await ctx.wait_until(lambda: bool(of("path.finished", path_id=-1)), 600.0):
            raise ScenarioFailed(f"the tour did not finish after the door reopened; "
                                 f"statuses: {statuses[-6:]}")
        announced = [e.detail.get("name") for e in of("tour.stop")]
        ctx.check("every stop announced in order", announced == [s.name for s in stops],
                  f"{announced}")
        ctx.check("visitor messages shown", [e.detail.get("message") for e in of("tour.stop")]
                  == [s.message for s in stops])
        ctx.check("the stop behind the door was reached after it reopened",
                  len(announced) > stops_before)
        ctx.check("one help request", len(of("help.requested")) == 1,
                  f"{len(of('help.requested'))}")
        ctx.check("never inside the closed doorway", intrusions == 0, f"{intrusions} samples")
        ctx.check("no collision", not of("collision"), str([e.detail for e in of("collision")]))
        ctx.goals_reached = len(announced)
        ctx.metrics["help_wait_s"] = resolved.detail.get("waited_s")
        ctx.metrics["door_closed_s"] = round(opened_at - closed_at, 3)
