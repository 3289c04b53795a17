"""The pose gate: the navigator drives only on a fresh pose from a working localisation.

Each cycle :meth:`PoseGate.check` looks at the newest ``/pose`` (``map``) and the localisation
status. A pose older than ``max_age_s`` is no pose. Without a pose, or while localisation
reports ``lost``, the rover holds still with its goal kept active; once that has lasted
``nav.controller.lost_timeout_s`` (clock seconds, counted from when it began) the goal is to be
aborted with a :class:`~curio.nav.api.LocalizationLostError` naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass

from curio.core.geometry import Pose2D
from curio.core.messages import LocalizationStatus, PoseWithCovariance
from curio.nav.api import LocalizationLostError

__all__ = ["PoseGate", "PoseVerdict"]


@dataclass(frozen=True)
class PoseVerdict:
    """What the gate says about one cycle.

    Attributes:
        pose: the pose to drive on (``map``); None: hold still.
        newly_lost: localisation has just been reported lost (the navigator says it holds).
        error: set when the hold has lasted too long: abort the goal with it.
        reason: a short note for the abort (``no pose``, ``lost``).
    """

    pose: Pose2D | None
    newly_lost: bool = False
    error: LocalizationLostError | None = None
    reason: str = ""


class PoseGate:
    """Pass a fresh pose from a working localisation; otherwise hold, then give up.

    Args:
        lost_timeout_s: how long to hold without a usable pose before giving up, seconds.
        max_age_s: a pose older than this (clock seconds) is no pose.
    """

    def __init__(self, lost_timeout_s: float, max_age_s: float = 1.0) -> None:
        self.lost_timeout_s = lost_timeout_s
        self.max_age_s = max_age_s
        self._no_pose_since: float | None = None
        self._lost_since: float | None = None

    def reset(self) -> None:
        """A new goal: no hold has begun."""
        self._no_pose_since = None
        self._lost_since = None

    def check(self, pose: PoseWithCovariance | None, loc: LocalizationStatus | None,
              now_s: float) -> PoseVerdict:
        """Judge the newest pose and localisation status at clock time ``now_s``."""
        if pose is None or now_s - pose.stamp > self.max_age_s:
            if self._no_pose_since is None:
                self._no_pose_since = now_s
            return self._hold(self._no_pose_since, now_s, "no pose in map",
                              "localisation is not running", "no pose")
        self._no_pose_since = None
        if loc is not None and loc.state == "lost":
            newly_lost = self._lost_since is None
            if self._lost_since is None:
                self._lost_since = now_s
            return self._hold(self._lost_since, now_s, "localisation lost",
                              "set the pose on the dashboard", "lost", newly_lost)
        self._lost_since = None
        return PoseVerdict(pose.pose)

    def _hold(self, since_s: float, now_s: float, what: str, advice: str, reason: str,
              newly_lost: bool = False) -> PoseVerdict:
        error = None
        if now_s - since_s > self.lost_timeout_s:
            error = LocalizationLostError(f"{what} for {self.lost_timeout_s:g} s "
                                          f"(nav.controller.lost_timeout_s): {advice}")
        return PoseVerdict(None, newly_lost, error, reason)
