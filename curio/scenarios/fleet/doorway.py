"""The ``doorway`` fleet scenario: two rovers meet in the default building's narrowest doorway.

The workshop's doorway (x 9.0..9.9 at y 9.5..9.65, 0.9 m wide; the rovers are 0.62 m wide
and 0.66 m long) joins the corridor and the workshop. ``r1`` starts in the corridor west of it
and is sent into the workshop; ``r2`` starts in the workshop and is sent into the corridor east
of it: both plans cross the doorway in opposite directions at about the same time. The seed
jitters both starts (±0.4 m along, ±0.15 m across, ±0.3 rad) and delays one rover by up to 2 s,
so every seed is a different meeting.

Success: both goals reached within ``default_duration_s`` of simulated time (no deadlock), no
rover-rover collision. Metrics: ``rover_rover_collisions``, ``rover_rover_encounters``,
``longest_standoff_s`` (the longest a rover held for the other), ``time_to_both_s``.
"""

from __future__ import annotations

import math

import numpy as np

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.scenarios.fleet.base import FleetArgs, FleetContext, FleetScenario

__all__ = ["DoorwayScenario"]

CORRIDOR_START = (6.3, 8.35, 0.0)
WORKSHOP_START = (10.6, 12.3, -math.pi / 2)
GOALS = {"r1": Pose2D(8.6, 12.3, math.pi / 2), "r2": Pose2D(12.6, 8.3, 0.0)}


class DoorwayScenario(FleetScenario):
    """Two rovers through the 0.9 m workshop doorway in opposite directions."""

    name = "doorway"
    description = "two rovers meet in the narrowest doorway of the default building"
    default_rovers = 2
    default_duration_s = 180.0

    def starts(self, n: int, seed: int) -> list[tuple[float, float, float]]:
        """The corridor and workshop starts, jittered by the seed."""
        if n != 2:
            raise ValueError(f"the doorway scenario has 2 rovers, not {n}")
        rng = np.random.default_rng(seed)
        a, b = CORRIDOR_START, WORKSHOP_START
        ja = rng.uniform([-0.4, -0.15, -0.3], [0.4, 0.15, 0.3])
        jb = rng.uniform([-0.15, -0.4, -0.3], [0.15, 0.4, 0.3])
        return [(a[0] + ja[0], a[1] + ja[1], a[2] + ja[2]),
                (b[0] + jb[0], b[1] + jb[1], b[2] + jb[2])]

    def configure(self, cfg: Config, args: FleetArgs) -> Config:
        """No behaviour-tree autostart: the script sends the goals."""
        bt = cfg.bt.model_copy(update={"autostart_path": None, "speak": False})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: FleetContext) -> None:
        """Send both goals (one maybe a little later), wait for both, score."""
        rng = np.random.default_rng(ctx.args.seed + 1000)
        delay = float(rng.uniform(0.0, 2.0))
        late = "r1" if rng.uniform() < 0.5 else "r2"
        await ctx.sleep(2.0)  # localisation settles
        t0 = ctx.now()
        for name in ("r1", "r2"):
            if name != late:
                ctx.press(name, "goto", goal=GOALS[name])
        await ctx.sleep(delay)
        ctx.press(late, "goto", goal=GOALS[late])
        ctx.record("script", action="goals sent", late=late, delay_s=round(delay, 2))

        def arrived(name: str) -> bool:
            return bool(ctx.events("nav.goal_succeeded", name))

        def finished(name: str) -> bool:
            return bool(ctx.events("nav.goal_succeeded", name) or
                        ctx.events("nav.goal_aborted", name))

        await ctx.wait_until(lambda: finished("r1") and finished("r2"),
                             self.default_duration_s - 10.0, poll_s=0.5)
        both = arrived("r1") and arrived("r2")
        ctx.metrics["time_to_both_s"] = round(ctx.now() - t0, 2) if both else None
        ctx.check("both rovers through the doorway (no deadlock)", both,
                  f"r1 {'arrived' if arrived('r1') else 'did not'}, "
                  f"r2 {'arrived' if arrived('r2') else 'did not'}")
        ctx.check("no rover-rover collision", not ctx.rover_rover_collisions(),
                  str(ctx.rover_rover_collisions()[:2]))
