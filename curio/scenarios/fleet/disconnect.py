"""The ``disconnect`` fleet scenario: a rover loses its link in the middle of a tour.

Two rovers and the manager. The manager holds a long tour (gallery, lab, meeting room) and an
operator asks for it: the manager must give it to ``r1``, the rover nearer its first stop
(``r2`` waits further back in the lobby). When ``r1`` has reached the first stop its link is
cut (its Zenoh session closes, as a pulled access point would do): ``r1`` must carry on
safely by itself — it reports ``fleet.link_lost`` and keeps guiding — while the manager, after
``fleet.manager.redispatch_after_s`` (20 s here) without hearing from it, gives the tour to
``r2``. When ``r1``'s link comes back (``RESTORE_AFTER_S`` after the cut) it is still on the
tour the manager gave away, so the manager tells it to stop and go home.

Checks: the nearer rover got the tour; ``r1`` reported the lost link and reached at least one
more stop after the cut; the tour was re-dispatched to ``r2`` and ``r2`` finished it; ``r1``
was stopped and sent home after it came back; no collision; both home at the end.
"""

from __future__ import annotations

from typing import Any

from curio.core.config import Config
from curio.fleet.manager.dispatch import Job
from curio.scenarios.fleet.base import FleetArgs, FleetContext, FleetScenario, FleetScenarioFailed
from curio.tours.model import stop_from_json

__all__ = ["DisconnectScenario"]

HOMES = [(0.0, 0.0, 0.0), (-3.0, 0.5, 0.0)]
TOUR: list[dict[str, Any]] = [{"name": "Gallery", "x_m": 12.5, "y_m": 1.5, "dwell_s": 10.0},
        {"name": "Lab", "x_m": 20.0, "y_m": 0.0, "dwell_s": 10.0},
        {"name": "Meeting room", "x_m": 19.5, "y_m": 12.0, "dwell_s": 10.0}]
REDISPATCH_AFTER_S = 20.0
RESTORE_AFTER_S = 60.0


class DisconnectScenario(FleetScenario):
    """A rover's link is cut mid-tour (see the module docstring)."""

    name = "disconnect"
    description = "a rover loses its link mid-tour: it carries on, the tour is re-dispatched"
    default_rovers = 2
    default_duration_s = 1500.0
    wants_manager = True

    def starts(self, n: int, seed: int) -> list[tuple[float, float, float]]:
        """``r1`` near the lobby's east side, ``r2`` further back."""
        if n != 2:
            raise ValueError(f"the disconnect scenario has 2 rovers, not {n}")
        return list(HOMES)

    def tours(self) -> dict[str, list[dict[str, Any]]]:
        """One long tour."""
        return {"Long tour": list(TOUR)}

    def configure(self, cfg: Config, args: FleetArgs) -> Config:
        """The tour tree; the manager re-dispatches after 20 s offline."""
        bt = cfg.bt.model_copy(update={"tree": "tour", "autostart_path": None, "speak": False,
                                       "tour_stops": [], "tour_loop": False})
        manager = cfg.fleet.manager.model_copy(update={"redispatch_after_s": REDISPATCH_AFTER_S})
        fleet = cfg.fleet.model_copy(update={"manager": manager})
        return cfg.model_copy(update={"bt": bt, "fleet": fleet})

    async def run(self, ctx: FleetContext) -> None:
        """Ask for the tour, cut r1's link at its first stop, restore it, score."""
        mgr = ctx.manager
        tour = mgr.tours.create("Long tour", [stop_from_json(s) for s in self.tours()["Long tour"]],
                                actor="scenario")
        await ctx.sleep(4.0)
        job = mgr.dispatch_tour(tour.id, "operator:scenario")
        if not await ctx.wait_until(lambda: job.state == "running", 60.0):
            raise FleetScenarioFailed(f"the tour did not start: {job.to_json()}")
        ctx.check("the manager chose the rover nearer the first stop", job.rover == "r1",
                  f"chose {job.rover}")
        if not await ctx.wait_until(lambda: bool(ctx.events("tour.stop", "r1")), 300.0):
            raise FleetScenarioFailed("r1 never reached the first stop")
        ctx.cut("r1")
        cut_at = ctx.now()
        ctx.record("script", action="r1's link cut")
        await ctx.wait_until(lambda: job.rover == "r2" and job.state == "running", 120.0)
        ctx.metrics["redispatched_after_s"] = round(ctx.now() - cut_at, 1)
        await ctx.sleep(max(0.0, cut_at + RESTORE_AFTER_S - ctx.now()))
        ctx.restore("r1")
        ctx.record("script", action="r1's link restored")
        await ctx.wait_until(lambda: job.state in ("done", "dropped"), 900.0)
        await ctx.wait_until(lambda: self._home(ctx), 600.0)
        self._score(ctx, job, cut_at)

    @staticmethod
    def _home(ctx: FleetContext) -> bool:
        return all((t := ctx.truth(r.name)) is not None and
                   t.distance_to(r.app.robot.home) < 0.6 for r in ctx.rovers)

    @staticmethod
    def _score(ctx: FleetContext, job: Job, cut_at: float) -> None:
        lost = [e for e in ctx.events("fleet.link_lost", "r1") if e["t"] >= cut_at]
        stops_after = [e for e in ctx.events("tour.stop", "r1") if e["t"] > cut_at]
        ctx.check("r1 reported its lost link", bool(lost))
        ctx.check("r1 kept guiding after the cut", bool(stops_after),
                  f"{len(stops_after)} stops reached after the cut")
        ctx.check("the tour was re-dispatched to r2 and finished there",
                  job.state == "done" and job.rover == "r2", str(job.to_json()["history"]))
        orphan = [e for e in ctx.manager.log if e["kind"] == "dispatch.orphan_stopped"]
        stopped = [e for e in ctx.events("tour.stopped", "r1") if e["t"] > cut_at]
        finished = [e for e in ctx.events("tour.finished", "r1") if e["t"] > cut_at]
        ctx.check("r1 was stopped and sent home after it came back, or had finished",
                  (bool(orphan) and bool(stopped)) or bool(finished),
                  f"orphan stop {bool(orphan)}, stopped {len(stopped)}, finished {len(finished)}")
        ctx.check("no collision", not ctx.events("collision"),
                  str(ctx.events("collision")[:2]))
        far = [r.name for r in ctx.rovers if (t := ctx.truth(r.name)) is None
               or t.distance_to(r.app.robot.home) > 0.6]
        ctx.check("both rovers home at the end", not far, f"away: {far}")
        ctx.metrics.update({"job": job.to_json(), "r1_stops_after_cut": len(stops_after),
                            "redispatches": ctx.manager.dispatcher.redispatches,
                            "cut_at_s": round(cut_at, 1),
                            "restored_at_s": round(cut_at + RESTORE_AFTER_S, 1)})
