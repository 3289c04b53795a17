"""The path follower: drives the current route one waypoint at a time through the navigator.

This is the execution half of the original's ``follow_path.py`` (original-system.md §3.3–3.4),
with its reset rules kept and its defects fixed. It never awaits: :meth:`PathFollower.step` is
called once per tree tick, sends navigator goals and polls their :class:`GoalHandle`.

Waypoint counter rules (the original's, §3.4):

* it returns to 0 at the end of a path, when switching to path 0 (Home), and when leaving Home
  for another path;
* a switch between two other paths keeps it (the *equivalent waypoint*): heading to waypoint 2
  of path 1 and told path 3, the rover heads to waypoint 2 of path 3; if path 3 is too short,
  it starts path 3 from its first waypoint and says so (the original silently ignored it, §9.13);
* pause and resume keep it (the same waypoint is sent again);
* an aborted or rejected waypoint does **not** advance it (§9.12): Resume retries it.

Outputs: STATUS (``Moving to (x,y)``, ``Arrived at (x,y)``, ``Going home``...), PROGRESS (one
state per waypoint), EVENTS ``waypoint.reached``, ``waypoint.failed``, ``path.started``,
``path.finished``, ``tour.stop``. A route may carry tour stops (name, dwell time, message):
on arrival the follower dwells there and announces the stop before moving on, and a looping
route starts again after its last stop. With :attr:`PathFollower.manners` (the guide's manners
among people, ``curio/people/guide.py``) the follower tells them where it drives, asks them
at a tour stop, and leaves a stop only when they say the way out is clear.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import Event, Progress, StatusText
from curio.core.topics import EVENTS, PROGRESS, STATUS
from curio.nav.api import GoalHandle, GoalState

from .paths import HOME_PATH_ID, NamedPath, format_xy

__all__ = ["BLOCKING_CODES", "PathFollower", "Phase", "Route", "StatusSink", "Stop",
           "StopManners"]

log = logging.getLogger("curio.bt.follower")

TOUR_ROUTE_ID = -1

# Navigation failures that mean "the way is blocked" (after the navigator's recovery): the tree
# asks a person for help instead of giving up (or skipping a tour stop).
BLOCKING_CODES = frozenset({"no_path", "no_progress", "controller_failed"})

Phase = Literal["idle", "moving", "dwelling", "held", "finished", "failed", "interrupted"]


@dataclass(frozen=True, slots=True)
class Stop:
    """One waypoint of a route in ``map`` (metres, radians), with optional tour details."""

    x_m: float
    y_m: float
    yaw_rad: float | None = None
    name: str = ""
    dwell_s: float = 0.0
    message: str = ""

    @property
    def is_tour_stop(self) -> bool:
        """Whether arriving here is announced and dwelt at."""
        return bool(self.name or self.message) or self.dwell_s > 0.0

    def label(self) -> str:
        """``(x,y)`` as shown to the operator."""
        return format_xy(self.x_m, self.y_m)


@dataclass(frozen=True, slots=True)
class Route:
    """What the follower drives: a path of the path manager, or the tour (id −1)."""

    id: int
    name: str
    stops: tuple[Stop, ...]
    loop: bool = False
    skip_failed: bool = False

    @staticmethod
    def from_path(path: NamedPath) -> Route:
        """A route over a :class:`NamedPath`'s waypoints (a copy: later edits don't move it)."""
        return Route(path.id, path.name,
                     tuple(Stop(w.x_m, w.y_m, w.yaw_rad) for w in path.waypoints))

    def __len__(self) -> int:
        return len(self.stops)


class StopManners(Protocol):
    """How the guide behaves at tour stops (``curio/people/guide.py``)."""

    def driving_to(self, tour_stop: bool) -> None:
        """The follower drives to its next waypoint (a tour stop or not)."""

    def arrived(self) -> None:
        """The rover has reached a tour stop."""

    def dwelling(self) -> None:
        """Once per tick while dwelling at a stop."""

    def may_leave(self, next_xy: tuple[float, float] | None) -> bool:
        """Whether the rover may leave the stop for ``next_xy`` (map, m) now."""


class StatusSink:
    """Publishes STATUS and PROGRESS only when they change, and events on EVENTS."""

    def __init__(self, bus: Bus, clock: Clock) -> None:
        self.bus = bus
        self.clock = clock
        self.text = ""
        self.state = ""
        self._progress: tuple[int, str, tuple[str, ...], int] | None = None

    def status(self, text: str, state: str) -> None:
        """Publish the operator's status line if it changed."""
        if (text, state) != (self.text, self.state):
            self.text, self.state = text, state
            self.bus.publish(STATUS, StatusText(self.clock.now(), text, state))

    def progress(self, path_id: int, name: str, states: list[str], index: int) -> None:
        """Publish per-waypoint progress if it changed."""
        key = (path_id, name, tuple(states), index)
        if key != self._progress:
            self._progress = key
            self.bus.publish(PROGRESS, Progress(self.clock.now(), path_id, name,
                                                tuple(states), index))

    def event(self, kind: str, **detail: Any) -> None:
        """Publish a reliable event."""
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, detail))


@dataclass
class _Dwell:
    until_s: float = 0.0
    remaining_s: float = 0.0


@dataclass
class FollowerSnapshot:
    """The follower's state for the blackboard and tests."""

    route_id: int | None
    route_name: str
    index: int
    phase: Phase
    states: list[str] = field(default_factory=list)
    goal_state: str = ""


class PathFollower:
    """Drives a :class:`Route` through a navigator with the original's counter rules.

    Args:
        navigator: anything with ``send_goal(poses, tag=)``, ``cancel()`` and ``active``
            (curio/nav/api.py); None means navigation is not running (goals then fail with a
            message to the operator).
        sink: where status, progress and events go.
        clock: for dwell times.
        speak: called with a visitor message at each tour stop (never blocks).
    """

    def __init__(
        self,
        navigator: Any,
        sink: StatusSink,
        clock: Clock,
        speak: Callable[[str], None] | None = None,
    ) -> None:
        self.navigator = navigator
        self.sink = sink
        self.clock = clock
        self.speak = speak
        self.route: Route | None = None
        self.index = 0
        self.states: list[str] = []
        self.phase: Phase = "idle"
        self.handle: GoalHandle | None = None
        self.hold_reason = ""
        self._dwell = _Dwell()
        self._held_phase: Phase = "idle"
        self.goals_sent = 0
        self.last_error = ""
        self.last_error_code = ""
        self.manners: StopManners | None = None  # set by curio/people/wiring.py

    # --- queries ----------------------------------------------------------------------------

    @property
    def route_id(self) -> int | None:
        """The id of the current route, or None."""
        return self.route.id if self.route is not None else None

    @property
    def driving(self) -> bool:
        """True while a goal of ours is PENDING or ACTIVE (the rover should be moving)."""
        return self.phase == "moving" and self.handle is not None and not self.handle.done

    @property
    def failed_blocked(self) -> bool:
        """True when the last waypoint failed because the way is blocked (no path, no progress
        after recovery): a person may be able to clear it."""
        return self.phase == "failed" and self.last_error_code in BLOCKING_CODES

    @property
    def active(self) -> bool:
        """True while a route is in progress (moving, dwelling or held)."""
        return self.phase in ("moving", "dwelling", "held")

    def current_stop(self) -> Stop | None:
        """The stop being driven to (or dwelt at), if any."""
        if self.route is None or not 0 <= self.index < len(self.route):
            return None
        return self.route.stops[self.index]

    def snapshot(self) -> FollowerSnapshot:
        """A copy of the state (for the blackboard)."""
        return FollowerSnapshot(self.route_id, self.route.name if self.route else "",
                                self.index, self.phase, list(self.states),
                                self.handle.state.value if self.handle else "")

    def owns(self, handle: GoalHandle | None) -> bool:
        """Whether ``handle`` is the goal this follower sent last."""
        return handle is not None and handle is self.handle

    # --- commands ---------------------------------------------------------------------------

    def switch(self, route: Route) -> str:
        """Switch to ``route`` with the original's counter rules; return the operator message.

        Raises:
            ValueError: the route has no waypoints (message for the operator).
        """
        if len(route) == 0:
            raise ValueError(f"Path {route.id} ({route.name}) has no waypoints yet; add some "
                             "on the map first.")
        previous = self.route_id
        index = self.index
        note = ""
        if previous in (None, HOME_PATH_ID, TOUR_ROUTE_ID) or route.id in (HOME_PATH_ID,
                                                                           TOUR_ROUTE_ID):
            index = 0
        elif index >= len(route):
            note = (f" It has {len(route)} waypoint{'s' if len(route) != 1 else ''}, fewer than "
                    f"the {index + 1} the rover had reached on path {previous}, so it starts "
                    "from its first waypoint.")
            index = 0
        self._abandon_current()
        self.route = route
        self.index = index
        self.states = ["skipped" if i < index else "pending" for i in range(len(route))]
        self._dwell = _Dwell()
        self.hold_reason = ""
        self.sink.event("path.started", path_id=route.id, name=route.name, index=index)
        self._drive()
        if route.id == HOME_PATH_ID:
            return "Going home."
        start = f" from waypoint {index + 1}" if index else ""
        return f"Following path {route.id} ({route.name}){start}.{note}"

    def hold(self, reason: str) -> None:
        """Stop where we are (pause, e-stop, help): cancel our goal, keep the waypoint."""
        if self.phase == "held":
            self.hold_reason = reason
            return
        self._held_phase = self.phase
        if self.phase == "dwelling":
            self._dwell.remaining_s = max(0.0, self._dwell.until_s - self.clock.now())
        self._cancel_ours()
        if self.phase in ("moving", "dwelling"):
            self.phase = "held"
            if 0 <= self.index < len(self.states) and self.states[self.index] == "active":
                self.states[self.index] = "pending"
            self._publish_progress()
        self.hold_reason = reason

    def resume(self) -> bool:
        """Continue after :meth:`hold` at the same waypoint; False if nothing was held.

        A failed waypoint is retried. A finished or idle follower stays as it is (the original
        restarted a finished path on resume, §9.14).
        """
        self.hold_reason = ""
        if self.route is None:
            return False
        if self.phase == "held":
            if self._held_phase == "dwelling":
                self.phase = "dwelling"
                self._dwell.until_s = self.clock.now() + self._dwell.remaining_s
                self._publish_status()
                return True
            self._drive()
            return True
        if self.phase in ("failed", "interrupted"):
            self._drive()
            return True
        return False

    def stop(self, reason: str = "") -> None:
        """Abandon the route (operator cancel, foreign goal): nothing is resumed later."""
        self._abandon_current()
        self.phase = "idle"
        self.hold_reason = ""
        if reason:
            self.sink.status(reason, "idle")

    def _abandon_current(self) -> None:
        self._cancel_ours()
        if self.route is not None and self.phase in ("moving", "held", "dwelling"):
            for i in range(self.index, len(self.states)):
                if self.states[i] in ("active", "pending"):
                    self.states[i] = "skipped"
            self._publish_progress()

    def _cancel_ours(self) -> None:
        nav = self.navigator
        if (self.handle is not None and not self.handle.done and nav is not None
                and nav.active is self.handle):
            nav.cancel()
        self.handle = None

    # --- driving ----------------------------------------------------------------------------

    def _drive(self) -> None:
        """Send the goal for the current waypoint."""
        stop = self.current_stop()
        assert self.route is not None and stop is not None
        self.phase = "moving"
        self.states[self.index] = "active"
        if self.navigator is None:
            self.handle = None
            self._fail("navigation is not running")
            return
        if self.manners is not None:
            self.manners.driving_to(stop.is_tour_stop)
        yaw = stop.yaw_rad
        if yaw is None and self.manners is not None and stop.is_tour_stop:
            yaw = math.nan  # the guide turns to face its group there instead
        if yaw is None:
            yaw = self._heading_towards(stop)
        pose = Pose2D(stop.x_m, stop.y_m, yaw)
        self.handle = self.navigator.send_goal(
            pose, tag=f"path {self.route.id} wp {self.index}")
        self.goals_sent += 1
        self._publish_status()
        self._publish_progress()

    def _heading_towards(self, stop: Stop) -> float:
        """A heading for a waypoint without one: along the segment from the previous waypoint."""
        assert self.route is not None
        if self.index > 0:
            prev = self.route.stops[self.index - 1]
            if (prev.x_m, prev.y_m) != (stop.x_m, stop.y_m):
                return math.atan2(stop.y_m - prev.y_m, stop.x_m - prev.x_m)
        if self.index + 1 < len(self.route):
            nxt = self.route.stops[self.index + 1]
            if (nxt.x_m, nxt.y_m) != (stop.x_m, stop.y_m):
                return math.atan2(nxt.y_m - stop.y_m, nxt.x_m - stop.x_m)
        return 0.0

    def step(self) -> Phase:
        """Poll the goal and move the route on; call once per tick. Returns the phase."""
        if self.phase == "moving":
            handle = self.handle
            if handle is None:
                self._drive()
                return self.phase
            state = handle.state
            if state is GoalState.SUCCEEDED:
                self._reached()
            elif state in (GoalState.ABORTED, GoalState.REJECTED):
                error = handle.error
                self._fail(str(error) if error is not None else state.value,
                           getattr(error, "code", state.value))
            elif state is GoalState.PREEMPTED:
                # Someone else's goal replaced ours (a dashboard goto) or cancelled it.
                self.phase = "interrupted"
                self.states[self.index] = "pending"
                self.handle = None
                self._publish_progress()
                self.sink.event("path.interrupted", path_id=self.route_id, index=self.index)
        elif self.phase == "dwelling":
            if self.manners is not None:
                self.manners.dwelling()
            if self.clock.now() >= self._dwell.until_s and self._may_leave():
                self._advance()
        return self.phase

    def _may_leave(self) -> bool:
        """Whether the manners let the rover leave the stop for the next waypoint."""
        if self.manners is None or self.route is None:
            return True
        nxt = self.index + 1
        if nxt >= len(self.route):
            nxt = 0 if self.route.loop else -1
        target = self.route.stops[nxt] if nxt >= 0 else None
        return self.manners.may_leave(None if target is None else (target.x_m, target.y_m))

    def _reached(self) -> None:
        assert self.route is not None
        stop = self.route.stops[self.index]
        self.states[self.index] = "reached"
        self.handle = None
        self.sink.event("waypoint.reached", path_id=self.route.id, index=self.index,
                        x_m=stop.x_m, y_m=stop.y_m, name=stop.name)
        self.sink.status(f"Arrived at {stop.label()}", "arrived")
        self._publish_progress()
        if stop.is_tour_stop:
            self.phase = "dwelling"
            self._dwell = _Dwell(until_s=self.clock.now() + stop.dwell_s)
            self.sink.event("tour.stop", name=stop.name, index=self.index, message=stop.message,
                            dwell_s=stop.dwell_s, x_m=stop.x_m, y_m=stop.y_m)
            if self.manners is not None:
                self.manners.arrived()
            self._publish_status()
            if stop.message and self.speak is not None:
                self.speak(stop.message)
            return
        self._advance()

    def _advance(self) -> None:
        assert self.route is not None
        self.index += 1
        if self.index < len(self.route):
            self._drive()
            return
        self.sink.event("path.finished", path_id=self.route.id, name=self.route.name,
                        reached=self.states.count("reached"), total=len(self.route))
        if self.route.loop:
            self.index = 0
            self.states = ["pending"] * len(self.route)
            self.sink.event("tour.loop", name=self.route.name)
            self._drive()
            return
        self.index = 0  # the original's reset rule: end of path
        self.phase = "finished"
        if self.manners is not None:
            self.manners.driving_to(False)
        self._publish_progress()

    def _fail(self, message: str, code: str = "nav_error") -> None:
        assert self.route is not None
        stop = self.route.stops[self.index]
        self.states[self.index] = "failed"
        self.last_error = message
        self.last_error_code = code
        self.handle = None
        self.sink.event("waypoint.failed", path_id=self.route.id, index=self.index,
                        x_m=stop.x_m, y_m=stop.y_m, error=code, message=message)
        self._publish_progress()
        if (self.route.skip_failed and self.navigator is not None
                and code not in BLOCKING_CODES):
            self._advance()
            return
        self.phase = "failed"
        self.sink.status(f"Could not reach {stop.label()}: {message}", "idle")

    # --- status -----------------------------------------------------------------------------

    def _publish_status(self) -> None:
        stop = self.current_stop()
        if stop is None or self.route is None:
            return
        if self.phase == "dwelling":
            text = f"At {stop.name or stop.label()}"
            if stop.message:
                text += f": {stop.message}"
            self.sink.status(text, "tour")
        elif self.route.id == HOME_PATH_ID:
            self.sink.status("Going home", "going_home")
        else:
            self.sink.status(f"Moving to {stop.label()}",
                             "tour" if self.route.id == TOUR_ROUTE_ID else "moving")

    def _publish_progress(self) -> None:
        if self.route is not None:
            self.sink.progress(self.route.id, self.route.name, self.states, self.index)
