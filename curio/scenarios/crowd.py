"""The ``crowd`` scenario: the guided tour (or one goal) among simulated visitors.

``curio sim crowd [--map YAML] [--visitors N] [--seed N] [--start X,Y,YAW --goal X,Y[,YAW]]``

* ``--visitors N`` visitors walk the world (default ``sim.crowd.visitors``, else 10): a
  social-force crowd of wanderers, groups that stand at exhibits, fast crossers and tour
  followers (``sim.crowd``; :mod:`curio.sim.crowd`).
* Without ``--goal``: the guided tour (``guided-tour``). On the default building it visits the
  configured ``bt.tour_stops``; on any other map (a stop of the configuration not free there)
  it visits three points of interest within 12 m of the start, 8 s at each, and goes home.
* With ``--goal``: drive from the start (``--start``, or a free pose) to the goal (``goto``).

Success: the tour finished (every stop announced, back home) or the goal reached — and no
collision the rover caused. People who walk into a standing rover are counted, not failed.

Metrics (besides the tour's or goto's): ``collisions_rover_at_fault`` (every contact the
rover made by moving: with people, walls, anything), ``collisions_person_at_fault`` (a
visitor walked into the rover while it stood still or moved away), ``min_person_distance_m``
(footprint to body edge, ground truth, whole run), ``time_below_0_3m_s``, ``encounters``
(a visitor within 1 m until farther than 1.5 m) and ``encounters_ok_fraction`` (those whose
minimum stayed ≥ 0.3 m; ``encounters_below_by_person``: those below 0.3 m where the rover was
not closing in on the visitor when they were nearest), ``tracks_mota`` / ``tracks_motp_m`` /
``tracks_velocity_rmse_mps`` (the tracker against the simulator's ground truth, CLEAR MOT),
``excuse_me``, ``help_requests``, ``nav_time_s`` (goal or tour: start to finish),
``visitors``, ``mode`` and ``controller`` (``aware`` or ``baseline``, from ``people.aware``).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from typing import Any

import numpy as np

from curio.core.config import Config, TourStopConfig
from curio.core.geometry import Pose2D
from curio.core.messages import PeopleTracks, SimPeople
from curio.core.topics import PEOPLE, PEOPLE_TRUTH
from curio.people.metrics import MotAccumulator, Proximity
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext
from curio.scenarios.goto import GotoScenario, pick_free_pose
from curio.scenarios.guided_tour import GuidedTourScenario

__all__ = ["CrowdScenario", "tour_stops_for"]

DEFAULT_VISITORS = 10
SAMPLE_S = 0.05
TOUR_RADIUS_M = 12.0


def _stops_fit(cfg: Config) -> bool:
    """Whether every configured tour stop holds the rover on ``sim.world``."""
    from curio.scenarios.goto import free_poses

    if not cfg.bt.tour_stops:
        return False
    pts, _ = free_poses(cfg, clearance_m=0.15)
    return all(np.hypot(pts[:, 0] - s.x_m, pts[:, 1] - s.y_m).min() < 0.1
               for s in cfg.bt.tour_stops)


def tour_stops_for(cfg: Config, start: Pose2D, count: int = 3) -> list[TourStopConfig]:
    """``count`` tour stops on ``sim.world``: open points of interest within 12 m of
    ``start``, at least 3 m apart, that the planner can reach from ``start``."""
    from curio.estimation.maps import load_map
    from curio.nav.api import NavError
    from curio.nav.planner import GlobalPlanner
    from curio.scenarios.goto import free_poses
    from curio.sim.walkmap import WalkMap

    grid = load_map(cfg.resolve(cfg.sim.world))
    walk = WalkMap(grid, anchor=(start.x, start.y))
    rng = np.random.default_rng([cfg.sim.seed, 0x7E])
    pois = walk.points_of_interest(rng, [], count=40, min_clearance_m=0.8)
    pts, cm = free_poses(cfg, clearance_m=0.3)
    planner = GlobalPlanner(cfg.nav.planner)
    chosen: list[tuple[float, float]] = []
    here = (start.x, start.y)
    for x, y in sorted(pois, key=lambda p: math.hypot(p[0] - start.x, p[1] - start.y)):
        if math.hypot(x - start.x, y - start.y) > TOUR_RADIUS_M or len(chosen) == count:
            break
        if any(math.hypot(x - a, y - b) < 3.0 for a, b in [*chosen, here]):
            continue
        if len(pts) == 0 or np.hypot(pts[:, 0] - x, pts[:, 1] - y).min() > 0.1:
            continue
        try:
            planner.plan(start, Pose2D(x, y, 0.0), cm.costs(), cm.resolution_m, cm.origin)
        except NavError:
            continue
        chosen.append((x, y))
    return [TourStopConfig(name=f"Stop {k + 1}", x_m=x, y_m=y, dwell_s=8.0,
                           message=f"This is stop {k + 1} of the tour.")
            for k, (x, y) in enumerate(chosen)]


class _CrowdGoto(GotoScenario):
    """``goto`` whose collision check counts only the collisions the rover caused."""

    def check_collisions(self, ctx: ScenarioContext) -> None:
        """No collision the rover caused (visitors walking into it are counted elsewhere)."""
        mine = [e for e in ctx.events_of("collision") if e["detail"].get("fault") != "person"]
        ctx.check("no_collision_rover_at_fault", not mine, f"{len(mine)} collisions")


class CrowdScenario(Scenario):
    """The guided tour or one goal among simulated visitors (see the module docstring)."""

    name = "crowd"
    description = ("the guided tour (or one goal: --start/--goal) among simulated visitors "
                   "(--visitors N)")
    default_duration_s = 1800.0

    def __init__(self) -> None:
        self.inner: Scenario = GuidedTourScenario()
        self.mode = "tour"

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """Visitors, then the tour (stops that fit the map) or the goal."""
        sim = cfg.sim.model_copy()
        if args.visitors is None and sim.crowd.visitors == 0:
            sim.crowd = sim.crowd.model_copy(update={"visitors": DEFAULT_VISITORS})
        cfg = cfg.model_copy(update={"sim": sim})
        if args.goal is not None:
            self.mode, self.inner = "goto", _CrowdGoto()
            return self.inner.configure(cfg, args)
        if not _stops_fit(cfg):
            start = Pose2D(*(sim.start or cfg.robot.home))
            if args.start is None:
                start = pick_free_pose(cfg, np.random.default_rng([sim.seed, 0x5A]),
                                       clearance_m=0.4)
                sim = sim.model_copy(update={"start": start.as_tuple()})
            cfg = cfg.model_copy(update={"sim": sim})
            robot = cfg.robot.model_copy(update={"home": start.as_tuple()})
            bt = cfg.bt.model_copy(update={"tour_stops": tour_stops_for(cfg, start)})
            cfg = cfg.model_copy(update={"robot": robot, "bt": bt})
        return self.inner.configure(cfg, args)

    async def run(self, ctx: ScenarioContext) -> None:
        """Run the tour or the goto while measuring closeness to people and the tracker."""
        prox = Proximity(np.asarray(ctx.app.robot.footprint_points, dtype=np.float64))
        mot = MotAccumulator(max_range_m=ctx.cfg.people.max_range_m)
        stop = asyncio.Event()
        watcher = asyncio.create_task(self._watch(ctx, prox, mot, stop), name="crowd-watch")
        t0 = ctx.now()
        try:
            await self.inner.run(ctx)
        finally:
            stop.set()
            watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watcher
            self._report(ctx, prox, mot, ctx.now() - t0)

    @staticmethod
    async def _watch(ctx: ScenarioContext, prox: Proximity, mot: MotAccumulator,
                     stop: asyncio.Event) -> None:
        """Sample ground truth every 50 ms; score every published set of tracks."""
        tracks_sub = ctx.bus.subscribe(PEOPLE, maxsize=64)
        truth_sub = ctx.bus.subscribe(PEOPLE_TRUTH, maxsize=64)
        truths: list[SimPeople] = []
        try:
            while not stop.is_set():
                world = ctx.world
                v, w = world.truth_twist
                ids, xy, radii = world.people_now()
                prox.add(ctx.now(), world.truth_pose, v, ids, xy, radii, w)
                truths = (truths + truth_sub.drain())[-20:]
                laser = world.laser_pose()
                for tr in tracks_sub.drain():
                    _score(mot, truths, tr, (laser.x, laser.y))
                await ctx.clock.sleep(SAMPLE_S)
        finally:
            tracks_sub.close()
            truth_sub.close()

    def _report(self, ctx: ScenarioContext, prox: Proximity, mot: MotAccumulator,
                elapsed_s: float) -> None:
        collisions = ctx.events_of("collision")
        rover = [e for e in collisions if e["detail"].get("fault") != "person"]
        people_rover = [e for e in rover if any(str(w).startswith(("visitor:", "person:"))
                                                for w in e["detail"].get("with", []))]
        stage = ctx.app.people.stage if ctx.app.people is not None else None
        m: dict[str, Any] = {
            "collisions_rover_at_fault": len(rover),
            "collisions_rover_with_people": len(people_rover),
            "collisions_person_at_fault": len(collisions) - len(rover),
            **prox.summary(),
            **mot.summary(),
            "excuse_me": len(ctx.events_of("people.excuse_me")),
            "help_requests": len(ctx.events_of("help.requested")),
            "visitors": ctx.cfg.sim.crowd.visitors,
            "mode": self.mode,
            "controller": "aware" if ctx.cfg.people.aware else "baseline",
            "yield_reviews_changed": None if stage is None else stage.changed,
        }
        if self.mode == "tour":
            m["nav_time_s"] = round(elapsed_s, 3)
        ctx.metrics.update(m)
        ctx.check("no collision the rover caused", not rover,
                  f"{len(rover)} ({len(people_rover)} with people)")


def _score(mot: MotAccumulator, truths: list[SimPeople], tracks: PeopleTracks,
           sensor: tuple[float, float]) -> None:
    """Pair a set of tracks with the ground truth nearest in time (≤ 50 ms) and score it."""
    if not truths:
        return
    best = min(truths, key=lambda t: abs(t.stamp - tracks.stamp))
    if abs(best.stamp - tracks.stamp) <= 0.05:
        mot.add(best, tracks, sensor)
