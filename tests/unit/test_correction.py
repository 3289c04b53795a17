"""The map→odom correction base: the correction, POSE, and what the first odometry does."""

from __future__ import annotations

import math

import pytest

from curio.core.bus import Bus
from curio.core.geometry import Pose2D
from curio.core.messages import LocalizationStatus, Odometry
from curio.core.topics import LOCALIZATION, MAP_TO_ODOM, POSE
from curio.estimation.correction import MapOdomPublisher
from curio.estimation.wiring import OdomRelay


class Fixed(MapOdomPublisher):
    def initial_pose(self) -> Pose2D:
        return Pose2D(1.0, 2.0, math.pi / 2)

    def publish_status(self, stamp: float) -> None:
        self.bus.publish(LOCALIZATION, LocalizationStatus(stamp, "ok"))

    def pose_covariance(self, odom: Odometry) -> tuple[float, ...]:
        return (1.0,) * 9


def test_the_first_odometry_sets_the_correction_then_each_makes_a_pose(bus: Bus) -> None:
    tf, pose, status = (bus.subscribe(t) for t in (MAP_TO_ODOM, POSE, LOCALIZATION))
    node = Fixed(bus)
    node.on_odom(Odometry(1.0, Pose2D(0.5, 0.0, 0.0)))
    (t,) = tf.drain()
    assert t.stamp == 1.0 and t.frame_id == "map" and t.child_frame_id == "odom"
    # odom's origin sits where the rover would have started: 0.5 m behind it in map.
    assert (t.transform.x, t.transform.y) == pytest.approx((1.0, 1.5))
    assert [s.state for s in status.drain()] == ["ok"]
    (p,) = pose.drain()
    assert (p.pose.x, p.pose.y, p.pose.yaw) == pytest.approx((1.0, 2.0, math.pi / 2))
    assert p.frame_id == "map" and p.covariance == (1.0,) * 9
    node.on_odom(Odometry(1.1, Pose2D(1.5, 0.0, 0.0)))  # 1 m further along odom's x
    assert tf.drain() == [] and status.drain() == []
    (p,) = pose.drain()
    assert (p.stamp, p.pose.x, p.pose.y) == pytest.approx((1.1, 1.0, 3.0))


def test_set_correction(bus: Bus) -> None:
    tf, pose = bus.subscribe(MAP_TO_ODOM), bus.subscribe(POSE)
    node = Fixed(bus)
    node.set_correction(Pose2D(4.0, 0.0, 0.0), Pose2D(1.0, 0.0, 0.0), 5.0)
    assert node.map_to_odom == Pose2D(3.0, 0.0, 0.0) and tf.drain()[0].stamp == 5.0
    node.publish_pose(5.5, Pose2D(2.0, 0.0, 0.0), (0.0,) * 9)
    assert pose.drain()[0].pose == Pose2D(5.0, 0.0, 0.0)


def test_the_dead_reckoning_relay(bus: Bus) -> None:
    from curio.core.topics import ODOM

    odom, pose, status = bus.subscribe(ODOM), bus.subscribe(POSE), bus.subscribe(LOCALIZATION)
    relay = OdomRelay(bus, Pose2D(2.0, 0.0, 0.0), relay_odom=True, compose_pose=True)
    msg = Odometry(1.0, Pose2D(0.0, 0.0, 0.0), covariance=(0.5,) * 9)
    relay.on_odom(msg)
    assert odom.drain() == [msg] and [s.state for s in status.drain()] == ["off"]
    (p,) = pose.drain()
    assert p.pose == Pose2D(2.0, 0.0, 0.0) and p.covariance == (0.5,) * 9
    only = OdomRelay(bus, Pose2D(), relay_odom=True, compose_pose=False)
    only.on_odom(msg)
    assert odom.drain() == [msg] and pose.drain() == [] and only.map_to_odom is None
