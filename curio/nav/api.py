"""The navigator's action interface and the typed navigation failures (Nav2-style).

The behaviour tree, the dashboard and the scenarios talk to navigation only through this:
``send_goal`` returns a :class:`GoalHandle` at once (never blocks the loop); its ``state`` moves
PENDING → ACTIVE → SUCCEEDED | ABORTED (with a typed ``error``) | PREEMPTED, or straight to
REJECTED for a goal that cannot be accepted (outside the map, in an obstacle).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol

from curio.core.geometry import Pose2D

__all__ = [
    "ControllerFailedError",
    "GoalBlockedError",
    "GoalHandle",
    "GoalOutsideMapError",
    "GoalState",
    "InvalidGoalError",
    "LocalizationLostError",
    "NavError",
    "Navigator",
    "NoPathError",
    "NoProgressError",
    "StartBlockedError",
    "StartOutsideMapError",
]


class NavError(Exception):
    """Base of every navigation failure; ``str()`` is a sentence for the operator."""

    code = "nav_error"


class StartOutsideMapError(NavError):
    """The rover's pose lies outside the map."""

    code = "start_outside_map"


class StartBlockedError(NavError):
    """The rover's pose is inside an obstacle in the costmap."""

    code = "start_blocked"


class InvalidGoalError(NavError):
    """The goal is not a usable pose (empty, not finite)."""

    code = "invalid_goal"


class GoalOutsideMapError(NavError):
    """The goal lies outside the map."""

    code = "goal_outside_map"


class GoalBlockedError(NavError):
    """The goal is inside an obstacle (and no free cell is near enough)."""

    code = "goal_blocked"


class NoPathError(NavError):
    """No collision-free path exists from the start to the goal."""

    code = "no_path"


class NoProgressError(NavError):
    """The rover made no progress for too long (after recovery)."""

    code = "no_progress"


class ControllerFailedError(NavError):
    """The local controller found no admissible command (after recovery)."""

    code = "controller_failed"


class LocalizationLostError(NavError):
    """Localisation is lost; navigating would be blind."""

    code = "localization_lost"


class GoalState(enum.Enum):
    """Lifecycle of a goal (ROS actionlib / Nav2 semantics)."""

    PENDING = "pending"
    ACTIVE = "active"
    SUCCEEDED = "succeeded"
    ABORTED = "aborted"
    PREEMPTED = "preempted"
    REJECTED = "rejected"

    @property
    def done(self) -> bool:
        """Whether the goal has finished (successfully or not)."""
        return self not in (GoalState.PENDING, GoalState.ACTIVE)


@dataclass
class GoalHandle:
    """A goal sent to the navigator; the navigator updates it in place.

    Attributes:
        goal_id: unique per navigator.
        poses: the waypoint(s) in ``map``; the last one is the final goal.
        state: current lifecycle state.
        error: the typed reason when ABORTED or REJECTED.
        distance_remaining_m: feedback, along the plan.
        eta_s: feedback, estimated time to arrival.
        current_index: index of the waypoint being driven to.
        recoveries: how many recovery actions were tried.
        tag: free text from the sender (e.g. ``path 1 wp 2``).
    """

    goal_id: int
    poses: list[Pose2D]
    state: GoalState = GoalState.PENDING
    error: NavError | None = None
    distance_remaining_m: float | None = None
    eta_s: float | None = None
    current_index: int = 0
    recoveries: int = 0
    tag: str = ""
    history: list[str] = field(default_factory=list)

    @property
    def done(self) -> bool:
        """Whether the goal has finished."""
        return self.state.done


class Navigator(Protocol):
    """What the behaviour tree and the dashboard use to drive the rover."""

    def send_goal(self, poses: Pose2D | list[Pose2D], *, tag: str = "") -> GoalHandle:
        """Accept a goal (or a waypoint sequence) and return its handle at once.

        A previous active goal is PREEMPTED. An unacceptable goal comes back REJECTED with
        ``error`` set.
        """
        ...

    def cancel(self) -> None:
        """Cancel the active goal (its state becomes PREEMPTED) and stop the rover."""
        ...

    @property
    def active(self) -> GoalHandle | None:
        """The goal being executed, if any."""
        ...
