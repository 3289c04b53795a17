"""The ``operator-demo`` scenario: the original's whole operator script, end to end.

original-system.md §8 item 29, on the default world (the lobby of ``maps/curio_building``,
home at (0, 0)), every step through the dashboard's reliable OPERATOR commands:

1. **Path 1 to its end**: ``select_path 1``; the rover drives (0.2,0) → (−0.2,0) → (0.5,0).
2. **Command 2**: ``select_path 2`` (the counter was reset at the end of path 1, so it starts at
   (1,1)).
3. **Pause** on the leg to (2,2): the goal is cancelled and the rover stands still.
4. **Resume**: the same waypoint (2,2) is sent again.
5. **Go Home** on the leg to (3,4): status ``Going home``.
6. **An obstacle is placed**: a barrier across the lobby between the rover and home (a
   ``world.add_box``), so no route leads home.
7. **HELP ME**: the blocked-path detector reports blocked, the tree asks for help once and
   holds (status ``Needs help``).
8. **The obstacle is removed** (``world.remove_object``).
9. **Thanks! and resume**: the way stays clear for ``bt.help_clear_s``, ``help.resolved``
   ("Thanks!"), the rover resumes the trip home and arrives at (0,0).

Checked (``ctx.check``): the status lines in order, the per-waypoint progress of each path,
one help request and its resolution in order, the rover standing still while paused and while
asking for help, no collision.
"""

from __future__ import annotations

from typing import Any

from curio.config import Config
from curio.geometry import Pose2D
from curio.messages import Event, Progress, StatusText
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed
from curio.topics import EVENTS, PROGRESS, STATUS

__all__ = ["OperatorDemoScenario"]

# The barrier: 0.2 m thick along x = 1.2 m across the whole lobby (y −6..7): home side sealed.
BARRIER = (1.2, 0.5, 0.2, 13.0)


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
        """The follow-path tree, no autostart, no speech; the start at home."""
        bt = cfg.bt.model_copy(update={"tree": "follow_path", "autostart_path": None,
                                       "speak": False})
        return cfg.model_copy(update={"bt": bt})

    async def run(self, ctx: ScenarioContext) -> None:
        """The script."""
        rec = _Recorder(ctx)
        try:
            await self._script(ctx, rec)
        finally:
            rec.close()

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

        # 6. An obstacle between the rover and home.
        await ctx.sleep(1.0)
        box = ctx.world.add_box(*BARRIER)
        ctx.record("script", action="obstacle placed", box=box)

        # 7. HELP ME.
        requested = await rec.wait_event("help.requested", 180.0)
        await rec.wait_status("Needs help", 5.0, mark)
        await ctx.sleep(2.0)
        moved = await self._still(ctx, 5.0)
        ctx.check("asking for help: the rover holds", moved < 0.05, f"moved {moved:.3f} m")

        # 8. The obstacle is removed.
        ctx.world.remove_object(box)
        ctx.record("script", action="obstacle removed", box=box)

        # 9. Thanks! and resume the trip home.
        resolved = await rec.wait_event("help.resolved", 120.0)
        ctx.check("help resolved with Thanks!", resolved.detail.get("message") == "Thanks!"
                  and resolved.detail.get("reason") == "clear", str(resolved.detail))
        ctx.check("one help request, then its resolution",
                  len(rec.of("help.requested")) == 1 and requested.stamp < resolved.stamp,
                  f"{len(rec.of('help.requested'))} requests")
        await rec.wait_event("path.finished", 240.0, path_id=0)
        tail = rec.texts(mark)
        ctx.check("home: status sequence", _in_order(
            tail, ["Going home", "Needs help", "Going home", "Arrived at (0,0)"]), f"{tail}")
        truth = ctx.truth() or Pose2D(99.0, 99.0)
        home = paths.get(0).waypoints[0]
        ctx.check("home: the rover is at home",
                  truth.distance_to(Pose2D(home.x_m, home.y_m)) < 0.4,
                  f"at ({truth.x:.2f}, {truth.y:.2f})")
        ctx.goals_reached = len(rec.of("waypoint.reached"))
        ctx.check("no rejected command", not rec.of("bt.command_rejected"),
                  str([e.detail for e in rec.of("bt.command_rejected")]))
        ctx.check("no collision", not rec.of("collision"),
                  str([e.detail for e in rec.of("collision")]))
        ctx.metrics["statuses"] = rec.texts()
        ctx.metrics["help_wait_s"] = resolved.detail.get("waited_s")
