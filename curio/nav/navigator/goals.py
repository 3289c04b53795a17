"""Goal tracking: the navigator's goal handles, waypoint by waypoint, and the goal events.

A goal sent to the navigator is ``pending`` until the next cycle activates it; the
activated goal is ``current`` (it stays current, done, until the next one is activated).
:class:`GoalTracker` moves handles through their states (:class:`~curio.nav.api.GoalState`),
advances along the waypoints, keeps the feedback (distance remaining along the plan plus the
legs still to come, m; ETA, s) and publishes the goal events on ``/events``, each with the
goal's id, tag and poses (``map``): ``nav.goal_accepted``, ``nav.goal_rejected``,
``nav.waypoint_reached``, ``nav.goal_succeeded``, ``nav.goal_aborted``, ``nav.goal_preempted``
(or the caller's kind, ``nav.goal_canceled``).
"""

from __future__ import annotations

import itertools
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import Event
from curio.core.topics import EVENTS
from curio.nav.api import GoalHandle, GoalState, NavError

__all__ = ["GoalTracker"]

_KINDS = {GoalState.SUCCEEDED: "nav.goal_succeeded", GoalState.ABORTED: "nav.goal_aborted",
          GoalState.PREEMPTED: "nav.goal_preempted", GoalState.REJECTED: "nav.goal_rejected"}


class GoalTracker:
    """The pending and the current goal (see the module docstring).

    Args:
        clock, bus: injected (event stamps, ``/events``).
    """

    def __init__(self, clock: Clock, bus: Bus) -> None:
        self.clock = clock
        self.bus = bus
        self._ids = itertools.count(1)
        self.pending: GoalHandle | None = None
        self.current: GoalHandle | None = None
        self.started_s = 0.0  # when the current goal was activated, clock seconds

    @property
    def active(self) -> GoalHandle | None:
        """The goal being executed (or about to be), if any; finished goals are not active."""
        for h in (self.pending, self.current):
            if h is not None and not h.done:
                return h
        return None

    def event(self, kind: str, handle: GoalHandle | None = None, **detail: Any) -> None:
        """Publish a navigation event, about ``handle`` when given."""
        d: dict[str, Any] = dict(detail)
        if handle is not None:
            d.setdefault("goal_id", handle.goal_id)
            if handle.tag:
                d.setdefault("tag", handle.tag)
            d.setdefault("goal", [[round(p.x, 3), round(p.y, 3)] for p in handle.poses])
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, d))

    def new(self, poses: list[Pose2D], tag: str) -> GoalHandle:
        """A handle with the next id for a goal or waypoint sequence (``map``)."""
        return GoalHandle(next(self._ids), poses, tag=tag)

    def reject(self, handle: GoalHandle, error: NavError) -> None:
        """The goal cannot be used: REJECTED with ``error``."""
        handle.state = GoalState.REJECTED
        handle.error = error
        handle.history.append(f"rejected: {error}")
        self.event("nav.goal_rejected", handle, code=error.code, message=str(error))

    def queue(self, handle: GoalHandle) -> None:
        """The goal to activate at the next cycle (the current one is let go)."""
        self.pending = handle
        self.current = None
        handle.history.append("pending")

    def clear(self) -> None:
        """No goal (after a cancel)."""
        self.pending = None
        self.current = None

    def activate(self) -> GoalHandle | None:
        """Make the pending goal the current one, ACTIVE from now; None when none waits."""
        handle = self.pending
        if handle is None:
            return None
        self.pending = None
        self.current = handle
        handle.state = GoalState.ACTIVE
        handle.history.append("active")
        self.started_s = self.clock.now()
        return handle

    def finish(self, handle: GoalHandle, state: GoalState, error: NavError | None, note: str,
               kind: str | None = None) -> None:
        """Move a goal to a final ``state`` and say so (with the time since activation)."""
        handle.state = state
        handle.error = error
        handle.history.append(f"{state.value}: {note}")
        detail: dict[str, Any] = {"note": note,
                                  "time_s": round(self.clock.now() - self.started_s, 3)}
        if error is not None:
            detail["code"] = error.code
            detail["message"] = str(error)
        self.event(kind or _KINDS[state], handle, **detail)

    def advance(self, handle: GoalHandle) -> bool:
        """The current waypoint is reached: move on to the next one (True), or, at the last,
        zero the feedback (False: the goal is reached)."""
        idx = handle.current_index
        if idx + 1 < len(handle.poses):
            self.event("nav.waypoint_reached", handle, index=idx)
            handle.current_index += 1
            return True
        handle.distance_remaining_m = 0.0
        handle.eta_s = 0.0
        return False

    @staticmethod
    def feedback(handle: GoalHandle, along_plan_m: float, speed_mps: float) -> None:
        """Feedback: ``along_plan_m`` to the current waypoint plus the legs still to come,
        and the time that takes at ``speed_mps`` (no less than 0.05 m/s)."""
        later = sum(handle.poses[k].distance_to(handle.poses[k + 1])
                    for k in range(handle.current_index, len(handle.poses) - 1))
        handle.distance_remaining_m = along_plan_m + later
        handle.eta_s = handle.distance_remaining_m / max(0.05, speed_mps)
