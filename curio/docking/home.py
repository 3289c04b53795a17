"""Home is the dock: one named pose, one source of truth.

Before, the rover had two homes: ``robot.home`` (where it started after a restart) and path 0
of the path manager (where Go Home drove), so moving home on the dashboard left a restarted
rover mislocalised. Now **home is the last waypoint of path 0**, persisted with the paths
(``<data_dir>/paths.json``); the waypoints before it are the route home. It is:

* the start pose at start-up (the composition root builds the robot model with it, so the
  simulator, the localiser, the tour estimates and the dashboard all use it);
* where Go Home ends, and the pose of the dock when ``dock.enabled`` (the docked pose of
  ``base_link``; the staging pose is ``dock.staging_distance_m`` straight out of it).

``robot.home`` in the config only seeds it: the first time (no paths file yet) path 0 ends at
``robot.home`` when the config sets it. Changing home (:meth:`HomeDock.set`, the dashboard's
``PUT /api/home``) rewrites path 0 and so the next start.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from curio.core.config import Config
from curio.core.geometry import Pose2D

__all__ = ["HomeDock", "PathsLike", "seed_home"]

HOME_PATH_ID = 0


class PathsLike(Protocol):
    """What home needs of the path manager (``curio/bt/paths.py``)."""

    @property
    def file(self) -> Any:
        """Where the paths are kept."""

    def get(self, path_id: int) -> Any:
        """A path with ``waypoints`` (``x_m``, ``y_m``, ``yaw_rad``)."""

    def set_home(self, x_m: float, y_m: float, yaw_rad: float | None) -> Any:
        """Replace the last waypoint of path 0."""


def seed_home(paths: PathsLike, cfg: Config, fresh: bool) -> None:
    """The first time (``fresh``: there was no paths file), path 0 ends at ``robot.home`` when
    the config sets it explicitly."""
    if fresh and "home" in cfg.robot.model_fields_set:
        x, y, yaw = cfg.robot.home
        paths.set_home(x, y, yaw)


class HomeDock:
    """The home (and dock) pose in ``map`` (see the module docstring).

    Args:
        paths: the path manager.
        staging_distance_m: the staging pose lies this far straight out of the dock.
    """

    def __init__(self, paths: PathsLike, staging_distance_m: float) -> None:
        self.paths = paths
        self.staging_distance_m = staging_distance_m

    def pose(self) -> Pose2D:
        """Home: the last waypoint of path 0 (a missing heading reads as 0)."""
        wp = self.paths.get(HOME_PATH_ID).waypoints[-1]
        return Pose2D(wp.x_m, wp.y_m, wp.yaw_rad if wp.yaw_rad is not None else 0.0)

    def route(self) -> list[Pose2D]:
        """The waypoints before home on path 0 (the way home), headings NaN when free."""
        wps = self.paths.get(HOME_PATH_ID).waypoints[:-1]
        return [Pose2D(w.x_m, w.y_m, w.yaw_rad if w.yaw_rad is not None else math.nan)
                for w in wps]

    def staging(self) -> Pose2D:
        """Where the final approach starts: facing the dock, ``staging_distance_m`` out."""
        return self.pose() @ Pose2D(-self.staging_distance_m, 0.0, 0.0)

    def set(self, pose: Pose2D) -> Pose2D:
        """Move home (and the dock) to ``pose``; return it."""
        self.paths.set_home(pose.x, pose.y, pose.yaw)
        return self.pose()

    def to_json(self) -> dict[str, Any]:
        """Home and staging poses for the dashboard."""
        home, staging = self.pose(), self.staging()
        return {"home": [home.x, home.y, home.yaw], "staging": [staging.x, staging.y,
                                                              staging.yaw]}
