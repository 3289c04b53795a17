"""The ``operator-demo`` scenario: the original's whole operator script, end to end.

original-system.md §8 item 29, on the default world (the lobby of ``maps/curio_building``,
home at (0, 0)), every step through the dashboard's reliable OPERATOR commands:

1. **Path 1 to its end**: ``select_path 1``; the rover drives (0.2,0) → (−0.2,0) → (0.5,0).
2. **Command 2**: ``select_path 2`` (the counter was reset at the end of path 1, so it starts at
   (1,1)).
3. **Pause** on the leg to (2,2): the goal is cancelled and the rover stands still.
4. **Resume**: the same waypoint (2,2) is sent again.
5. **Go Home** on the leg to (3,4): status ``Going home``, then ``Arrived at (0,0)``.
6. **A path clicked on the map** (created through the path manager, as the dashboard does):
   through the lobby archway and the corridor into the library, whose doorway is its only way
   in; ``select_path`` (leaving home: from its first waypoint).
7. **An obstacle is placed** in front of the rover: a cart filling the library doorway
   (``world.add_box``), so no route leads on.
8. **HELP ME**: the way is blocked and navigation's recovery does not free it; the tree asks
   for help once and holds (status ``Needs help``).
9. **The obstacle is removed** (``world.remove_object``): **Thanks! and resume**: the way stays
   clear for ``bt.help_clear_s``, ``help.resolved`` ("Thanks!"), and the rover resumes the
   path at the same waypoint and drives it to its end.

(The obstacle sits in a doorway, not across the lobby on the way home: in open floor the
planner rightly drives around a box, and a wall across the whole lobby is no longer the building
the localisation knows.)

Checked (``ctx.check``): the status lines in order, the per-waypoint progress of each path,
one help request and its resolution in order, the rover standing still while paused and while
asking for help, no collision.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path
from typing import Any

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event, Progress, StatusText
from curio.core.topics import EVENTS, PROGRESS, STATUS
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed

__all__ = ["OperatorDemoScenario"]

# A path "clicked" on the map: through the lobby archway, along the corridor, into the library
# (whose doorway at x 1.0..2.1, y 9.5..9.65 is its only way in).
LIBRARY_PATH = [(5.0, 5.5), (5.0, 8.3), (1.55, 8.3), (1.0, 11.6)]
DOORWAY = (1.55, 9.575)
TRIGGER_M = 2.4
# The obstacle: a 1.3 m × 0.4 m cart filling the library doorway.
CART = (1.55, 9.575, 1.3, 0.4)


class _Recorder:
    """Status lines, progress and events as the operator's dashboard would see them."""

    def __init__(self, ctx: ScenarioContext) -> None:
        self.ctx = ctx
        self.status_sub = ctx.bus.subscribe(STATUS)
        self.progress_sub = ctx.bus.subscribe(PROGRESS)
        self.events_sub = ctx.bus.subscribe(EVENTS)
        self.statuses: list[StatusText] = []
        self.progress: list[Progress] = []
        self.events: list[Event] = []

    def poll(self) -> None:
        self.statuses += self.status_sub.drain()
        self.progress += self.progress_sub.drain()
        self.events += self.events_sub.drain()

    def texts(self, since: int = 0) -> list[str]:
        self.poll()
        return [s.text for s in self.statuses[since:]]

    def of(self, kind: str, **match: Any) -> list[Event]:
        self.poll()
        return [e for e in self.events if e.kind == kind
                and all(e.detail.get(k) == v for k, v in match.items())]

    async def wait_event(self, kind: str, timeout_s: float, **match: Any) -> Event:
        found: list[Event] = []

        def seen() -> bool:
            found[:] = self.of(kind, **match)
            return bool(found)

        if not await self.ctx.wait_until(seen, timeout_s):
            raise ScenarioFailed(f"no {kind} {match or ''} within {timeout_s:g} s; last status: "
                                 f"{self.statuses[-1].text if self.statuses else 'none'}")
        return found[0]

    async def wait_status(self, text: str, timeout_s: float, since: int = 0) -> None:
        if not await self.ctx.wait_until(lambda: text in self.texts(since), timeout_s):
            raise ScenarioFailed(f"status '{text}' not shown within {timeout_s:g} s; "
                                 f"statuses: {self.texts(since)[-6:]}")

    def last_progress(self, path_id: int) -> tuple[str, ...]:
        self.poll()
        for p in reversed(self.progress):
            if p.path_id == path_id:
                return p.states
        return ()

    def close(self) -> None:
        self.status_sub.close()
        self.progress_sub.close()
        self.events_sub.close()


def _in_order(seq: list[str], expected: list[str]) -> bool:
    """Whether ``expected`` appears in ``seq`` as a subsequence (in this order)."""
    it = iter(seq)
    return all(any(item == want for item in it) for want in expected)


class OperatorDemoScenario(Scenario):
    """The original's operator script: path 1, path 2, pause, resume, Go Home, HELP ME."""

    name = "operator-demo"
    description = ("path 1 to its end, path 2, pause, resume, Go Home, an obstacle, HELP ME, "
                   "obstacle removed, Thanks! and home")
    default_duration_s = 900.0

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """The follow-path tree, no autostart, no speech, the configured default paths in a
        scratch file (the operator's saved paths are neither used nor changed)."""
        self._tmp = tempfile.mkdtemp(prefix="curio-operator-demo-")
        bt = cfg.bt.model_copy(update={"tree": "follow_path", "autostart_path": None,
                                       "speak": False,
                                       "paths_file": str(Path(self._tmp) / "paths.json")})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: ScenarioContext) -> None:
        """The script."""
        rec = _Recorder(ctx)
        try:
            await self._script(ctx, rec)
        finally:
            rec.close()
            shutil.rmtree(self._tmp, ignore_errors=True)

    async def _still(self, ctx: ScenarioContext, seconds: float) -> float:
        """How far the rover moved (ground truth, metres) over ``seconds``."""
        before = ctx.truth() or Pose2D()
        await ctx.sleep(seconds)
        after = ctx.truth() or Pose2D()
        return before.distance_to(after)

    async def _script(self, ctx: ScenarioContext, rec: _Recorder) -> None:
        paths = ctx.app.paths
        p1 = [w.label() for w in paths.get(1).waypoints]
        p2 = [w.label() for w in paths.get(2).waypoints]
        ctx.goals_total = len(p1) + 2 + 1
        await ctx.sleep(2.0)
        ctx.check("idle at start-up, no goal sent", rec.texts() == ["Idle"]
                  and ctx.app.navigator.active is None, f"statuses: {rec.texts()}")

        # 1. Path 1 to its end.
        ctx.press("select_path", path_id=1)
        await rec.wait_event("path.finished", 240.0, path_id=1)
        expected = [s for label in p1 for s in (f"Moving to {label}", f"Arrived at {label}")]
        ctx.check("path 1 status sequence", _in_order(rec.texts(), expected),
                  f"{rec.texts()}")
        ctx.check("path 1 progress all reached",
                  rec.last_progress(1) == ("reached",) * len(p1), str(rec.last_progress(1)))

        # 2. Command 2: starts from its first waypoint (the counter was reset).
        mark = len(rec.texts())
        ctx.press("select_path", path_id=2)
        await rec.wait_event("waypoint.reached", 180.0, path_id=2, index=0)
        ctx.check("path 2 starts at its first waypoint",
                  _in_order(rec.texts(mark), [f"Moving to {p2[0]}", f"Arrived at {p2[0]}",
                                              f"Moving to {p2[1]}"]), f"{rec.texts(mark)}")

        # 3. Pause on the leg to waypoint 1.
        await ctx.sleep(3.0)
        ctx.press("pause")
        await rec.wait_status("Paused", 5.0, mark)
        await ctx.sleep(2.0)  # let the rover brake
        moved = await self._still(ctx, 5.0)
        ctx.check("paused: the rover stands still", moved < 0.05, f"moved {moved:.3f} m")
        ctx.check("paused: progress keeps waypoint 1 pending",
                  rec.last_progress(2)[:2] == ("reached", "pending"), str(rec.last_progress(2)))

        # 4. Resume: the same waypoint again.
        mark = len(rec.texts())
        ctx.press("resume")
        await rec.wait_event("waypoint.reached", 180.0, path_id=2, index=1)
        ctx.check("resume: the same waypoint is driven to",
                  rec.texts(mark)[:2] == [f"Moving to {p2[1]}", f"Arrived at {p2[1]}"],
                  f"{rec.texts(mark)}")

        # 5. Go Home on the leg to waypoint 2.
        await ctx.sleep(2.0)
        mark = len(rec.texts())
        ctx.press("go_home")
        await rec.wait_status("Going home", 5.0, mark)
        ctx.check("path 2 progress: the last waypoint skipped for Go Home",
                  rec.last_progress(2) == ("reached", "reached", "skipped"),
                  str(rec.last_progress(2)))

        await rec.wait_event("path.finished", 240.0, path_id=0)
        ctx.check("home: status sequence", _in_order(
            rec.texts(mark), ["Going home", "Arrived at (0,0)"]), f"{rec.texts(mark)}")
        ctx.check("home: the rover is at home", self._at(ctx, paths.get(0).waypoints[0]),
                  f"at {ctx.truth()}")

        # 6. A path clicked on the map (as the dashboard does), through the library doorway.
        library = paths.create("Library", [])
        for x, y in LIBRARY_PATH:
            paths.add_waypoint(library.id, x, y)
        ctx.goals_total += len(LIBRARY_PATH)
        mark = len(rec.texts())
        ctx.press("select_path", path_id=library.id)

        def near_doorway() -> bool:
            truth = ctx.truth()
            return truth is not None and math.hypot(truth.x - DOORWAY[0],
                                                    truth.y - DOORWAY[1]) < TRIGGER_M

        if not await ctx.wait_until(near_doorway, 240.0, poll_s=0.2):
            raise ScenarioFailed(f"the rover never came near the library doorway; "
                                 f"statuses: {rec.texts(mark)[-5:]}")
        # 7. An obstacle (a cart) placed in the doorway in front of the rover: no way in.
        box = ctx.world.add_box(*CART)
        ctx.record("script", action="obstacle placed", box=box)

        # 8. HELP ME, once; the rover holds.
        requested = await rec.wait_event("help.requested", 180.0)
        await rec.wait_status("Needs help", 5.0, mark)
        await ctx.sleep(2.0)
        moved = await self._still(ctx, 5.0)
        ctx.check("asking for help: the rover holds", moved < 0.05, f"moved {moved:.3f} m")
        ctx.check("no thanks while the way is blocked", not rec.of("help.resolved"))

        # 9. The obstacle is removed: Thanks! and the path resumes to its end.
        ctx.world.remove_object(box)
        removed_at = ctx.now()
        ctx.record("script", action="obstacle removed", box=box)
        resolved = await rec.wait_event("help.resolved", 120.0)
        ctx.check("help resolved with Thanks! after the obstacle was removed",
                  resolved.detail.get("message") == "Thanks!"
                  and resolved.detail.get("reason") == "clear" and resolved.stamp >= removed_at,
                  str(resolved.detail))
        await rec.wait_event("path.finished", 240.0, path_id=library.id)
        ctx.check("one help request, then its resolution",
                  len(rec.of("help.requested")) == 1 and requested.stamp < resolved.stamp,
                  f"{len(rec.of('help.requested'))} requests")
        last = paths.get(library.id).waypoints[-1]
        ctx.check("resumed to the end of the path", _in_order(
            rec.texts(mark), ["Needs help", f"Moving to {last.label()}",
                              f"Arrived at {last.label()}"]), f"{rec.texts(mark)}")
        ctx.check("library path progress all reached",
                  rec.last_progress(library.id) == ("reached",) * len(LIBRARY_PATH),
                  str(rec.last_progress(library.id)))
        ctx.check("at the end of the path", self._at(ctx, last), f"at {ctx.truth()}")
        ctx.goals_reached = len(rec.of("waypoint.reached"))
        ctx.check("no rejected command", not rec.of("bt.command_rejected"),
                  str([e.detail for e in rec.of("bt.command_rejected")]))
        ctx.check("no collision", not rec.of("collision"),
                  str([e.detail for e in rec.of("collision")]))
        ctx.metrics["statuses"] = rec.texts()
        ctx.metrics["help_wait_s"] = resolved.detail.get("waited_s")

    @staticmethod
    def _at(ctx: ScenarioContext, wp: Any) -> bool:
        truth = ctx.truth()
        return truth is not None and truth.distance_to(Pose2D(wp.x_m, wp.y_m)) < 0.4
