"""The map→odom correction and the pose it makes (REP-105), for every node that owns it.

Odometry (``ODOM``: ``base_link`` in ``odom``) drifts; a localiser (or the mapper, or the dead
reckoning relay) corrects it with ``map → odom``, the pose of ``odom`` in ``map``. The
rover's pose in ``map`` is then ``POSE = map→odom ∘ odom``, published for every odometry
message with its stamp. :class:`MapOdomPublisher` is the one implementation of that plumbing:

* :meth:`~MapOdomPublisher.set_correction`: from a pose in ``map`` and the odometry pose of
  the same moment, ``map→odom = pose ∘ odom⁻¹``, published on ``MAP_TO_ODOM`` (latched);
* :meth:`~MapOdomPublisher.on_odom`: at the first odometry message the correction comes from
  :meth:`~MapOdomPublisher.initial_pose` and the status is published
  (:meth:`~MapOdomPublisher.publish_status`); every message gives a ``POSE`` with the node's
  covariance (:meth:`~MapOdomPublisher.pose_covariance`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from curio.core.bus import Bus
from curio.core.geometry import Pose2D
from curio.core.messages import Odometry, PoseWithCovariance, Transform
from curio.core.topics import MAP_TO_ODOM, POSE

__all__ = ["MapOdomPublisher"]


class MapOdomPublisher(ABC):
    """Owns ``map → odom`` and composes ``POSE`` (see the module docstring).

    Subclasses say where the rover starts in ``map`` (:meth:`initial_pose`), what status they
    report (:meth:`publish_status`) and how sure the pose is (:meth:`pose_covariance`).

    Args:
        bus: where ``MAP_TO_ODOM`` and ``POSE`` go.
    """

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.map_to_odom: Pose2D | None = None

    @abstractmethod
    def initial_pose(self) -> Pose2D:
        """Where the rover is in ``map`` at the first odometry message."""

    @abstractmethod
    def publish_status(self, stamp: float) -> None:
        """Publish the node's ``LOCALIZATION`` status (once the correction is first set)."""

    @abstractmethod
    def pose_covariance(self, odom: Odometry) -> tuple[float, ...]:
        """The row-major 3×3 covariance of ``POSE`` (x, y, yaw; m², rad²)."""

    def set_correction(self, pose_in_map: Pose2D, odom_pose: Pose2D, stamp: float) -> None:
        """``map→odom`` from the rover's pose in ``map`` and its odometry pose at ``stamp``."""
        self.map_to_odom = pose_in_map @ odom_pose.inverse()
        self.bus.publish(MAP_TO_ODOM, Transform(stamp, self.map_to_odom))

    def publish_pose(self, stamp: float, odom_pose: Pose2D,
                     covariance: tuple[float, ...]) -> None:
        """``POSE`` = map→odom ∘ ``odom_pose``, stamped with the odometry's time."""
        assert self.map_to_odom is not None
        self.bus.publish(POSE, PoseWithCovariance(stamp, self.map_to_odom @ odom_pose,
                                                  covariance, frame_id="map"))

    def on_odom(self, odom: Odometry) -> None:
        """Compose ``POSE`` for one odometry message (the first sets the correction)."""
        if self.map_to_odom is None:
            self.set_correction(self.initial_pose(), odom.pose, odom.stamp)
            self.publish_status(odom.stamp)
        self.publish_pose(odom.stamp, odom.pose, self.pose_covariance(odom))
