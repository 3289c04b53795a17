"""ROS 2 can listen: CDR checked by decoding with rosbags, type hashes and keys checked against
published values (ROS 2's generated code, rmw_zenoh's design document)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage, LaserScan, Odometry
from curio.fleet.ros2.msgs import DEFINITIONS, dds_type_name, serialize, type_hash
from curio.fleet.ros2.publisher import grid_msg, odometry_msg, ros_time, scan_msg, tf_msg
from curio.fleet.ros2.rmw import (
    BEST_EFFORT,
    TRANSIENT_LOCAL,
    Qos,
    attachment,
    node_token,
    publisher_token,
    qos_keyexpr,
    topic_keyexpr,
)

typesys = pytest.importorskip("rosbags.typesys")
STORE = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)

# RIHS01 hashes as published: std_msgs/String in rmw_zenoh's design document; the others in
# the type-hash constants of ROS 2's generated C code (rosidl, e.g.
# nav_msgs/msg/detail/odometry__struct.h).
PUBLISHED = {
    "std_msgs/msg/String": "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/LaserScan":
        "64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    "nav_msgs/msg/Odometry": "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "tf2_msgs/msg/TFMessage":
        "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "nav_msgs/msg/OccupancyGrid":
        "8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    "builtin_interfaces/msg/Time":
        "b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
}


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_type_hashes_match_the_published_ones(name: str) -> None:
    assert type_hash(name) == "RIHS01_" + PUBLISHED[name]


@pytest.mark.parametrize("name", sorted(DEFINITIONS))
def test_definitions_match_rosbags(name: str) -> None:
    theirs = STORE.fielddefs[name][1]
    assert [f[0] for f in theirs] == [f for f, _ in DEFINITIONS[name]]


def test_a_scan_decodes_with_rosbags() -> None:
    ranges = np.array([1.0, np.inf, np.nan, 2.5], dtype=np.float32)
    scan = LaserScan(3.0, -math.pi, math.pi / 2, 0.15, 12.0, ranges, scan_time_s=0.1)
    m = STORE.deserialize_cdr(scan_msg(scan, 1_700_000_000.25, "r1/laser"),
                              "sensor_msgs/msg/LaserScan")
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert m.header.frame_id == "r1/laser"
    assert m.angle_min == pytest.approx(-math.pi) and m.angle_max == pytest.approx(math.pi / 2)
    assert m.ranges[0] == 1.0 and np.isinf(m.ranges[1]) and np.isnan(m.ranges[2])
    assert len(m.intensities) == 0 and m.time_increment == pytest.approx(0.025)


def test_odometry_and_tf_decode_with_rosbags() -> None:
    odom = Odometry(0.0, Pose2D(1.0, 2.0, 0.5), 0.3, -0.1,
                    covariance=(0.1, 0.01, 0.0, 0.01, 0.2, 0.0, 0.0, 0.0, 0.05))
    m = STORE.deserialize_cdr(odometry_msg(odom, 10.0, ""), "nav_msgs/msg/Odometry")
    assert (m.header.frame_id, m.child_frame_id) == ("odom", "base_link")
    assert m.pose.pose.position.x == 1.0 and m.pose.pose.orientation.z == pytest.approx(
        math.sin(0.25))
    cov = np.asarray(m.pose.covariance).reshape(6, 6)
    assert (cov[0, 0], cov[0, 1], cov[1, 1], cov[5, 5]) == (0.1, 0.01, 0.2, 0.05)
    assert m.twist.twist.linear.x == 0.3 and m.twist.twist.angular.z == -0.1
    tf = STORE.deserialize_cdr(tf_msg([(5.0, "map", "odom", Pose2D(0.1, 0.2, 0.3)),
                                       (5.5, "odom", "base_link", Pose2D(1, 2, 3))]),
                               "tf2_msgs/msg/TFMessage")
    assert [(t.header.frame_id, t.child_frame_id) for t in tf.transforms] == [
        ("map", "odom"), ("odom", "base_link")]
    assert tf.transforms[1].transform.translation.y == 2.0
    assert tf.transforms[1].header.stamp.nanosec == 500_000_000


def test_a_map_decodes_with_rosbags_row_0_at_the_origin() -> None:
    data = np.zeros((3, 4), dtype=np.int8)
    data[0, 1] = 100
    data[2, 3] = -1
    grid = GridMessage(0.0, data, 0.05, Pose2D(-6.0, -6.0, 0.0))
    m = STORE.deserialize_cdr(grid_msg(grid, 1.0, ""), "nav_msgs/msg/OccupancyGrid")
    assert (m.info.width, m.info.height, m.info.origin.position.x) == (4, 3, -6.0)
    assert m.info.resolution == pytest.approx(0.05)
    assert list(m.data) == list(data.reshape(-1))


def test_cdr_header_and_alignment() -> None:
    raw = serialize("std_msgs/msg/String", {"data": "hi"})
    assert raw == b"\x00\x01\x00\x00" + struct.pack("<I", 3) + b"hi\x00"
    assert ros_time(-0.0) == {"sec": 0, "nanosec": 0}


def test_key_expressions_follow_the_design_document() -> None:
    # The design document's examples (demo_nodes_cpp's talker and listener).
    assert topic_keyexpr(0, "", "chatter", "std_msgs/msg/String") == (
        "0/chatter/std_msgs::msg::dds_::String_/RIHS01_" + PUBLISHED["std_msgs/msg/String"])
    assert topic_keyexpr(0, "/robot1", "chatter", "std_msgs/msg/String").startswith(
        "0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c")
    zid = "8b20917502ee955ac4476e0266340d5c"
    assert node_token(2, zid, 0, "", "talker") == f"@ros2_lv/2/{zid}/0/0/NN/%/%/talker"
    assert publisher_token(2, zid, 0, 10, "", "talker", "chatter", "std_msgs/msg/String",
                           Qos(depth=7)) == (
        f"@ros2_lv/2/{zid}/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/RIHS01_"
        + PUBLISHED["std_msgs/msg/String"] + "/::,7:,:,:,,")
    assert qos_keyexpr(Qos(depth=10)) == "::,10:,:,:,,"
    assert qos_keyexpr(Qos(reliability=BEST_EFFORT, depth=5)) == "2::,5:,:,:,,"
    assert qos_keyexpr(Qos(durability=TRANSIENT_LOCAL, depth=1)) == ":1:,1:,:,:,,"
    assert dds_type_name("tf2_msgs/msg/TFMessage") == "tf2_msgs::msg::dds_::TFMessage_"
    token = publisher_token(0, zid, 0, 1, "/r1", "curio", "scan", "sensor_msgs/msg/LaserScan",
                            Qos(reliability=BEST_EFFORT, depth=5))
    assert "/%r1/curio/%r1%scan/sensor_msgs::msg::dds_::LaserScan_/" in token


def test_attachment_layout() -> None:
    att = attachment(7, 1_700_000_000_123_456_789, bytes(range(16)))
    assert len(att) == 33
    assert struct.unpack_from("<qqB", att) == (7, 1_700_000_000_123_456_789, 16)
    assert att[17:] == bytes(range(16))
    with pytest.raises(ValueError):
        attachment(1, 1, b"short")
