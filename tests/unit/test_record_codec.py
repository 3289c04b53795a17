"""Recorded channels: Foxglove schemas, exact round trips of the replayed inputs, rounding of
the rest."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from curio.core import messages as m
from curio.core.geometry import Pose2D
from curio.core.topics import ALL_TOPICS
from curio.record.codec import REPLAY_INPUTS, Codec, decode, primary_channel
from curio.record.schemas import FOXGLOVE_SCHEMAS, curio_schema

CODEC = Codec(1_700_000_000.0)


def roundtrip(topic: str, msg: Any) -> Any:
    encoded = CODEC.encode(topic, msg)
    spec, data = encoded[0]
    assert spec.topic == primary_channel(topic)
    json.loads(data)  # valid JSON (no NaN / Infinity tokens)
    decoded = decode(spec.topic, data)
    assert decoded is not None and decoded[0].name == topic
    return decoded[1]


def test_every_topic_has_a_schema_naming_every_field() -> None:
    for topic in ALL_TOPICS:
        spec = CODEC.spec(topic.name)
        schema = json.loads(spec.schema)
        assert schema["title"] == spec.schema_name
        if spec.schema_name.startswith("curio."):
            fields = set(topic.type.__dataclass_fields__)
            assert set(schema["properties"]) == fields, topic.name
            assert all(schema["properties"][f] for f in fields), topic.name
    for name in ("foxglove.LaserScan", "foxglove.PoseInFrame", "foxglove.PosesInFrame",
                 "foxglove.Grid", "foxglove.FrameTransform", "foxglove.SceneUpdate",
                 "foxglove.Log"):
        assert FOXGLOVE_SCHEMAS[name]["type"] == "object"
    assert curio_schema(m.Imu)["properties"]["calibration"]["type"] == "array"


def test_scan_round_trip_is_exact_with_inf_nan_and_intensities() -> None:
    rng = np.random.default_rng(3)
    ranges = (rng.random(360) * 10).astype(np.float32)
    ranges[[3, 50]] = np.inf
    ranges[[7]] = np.nan
    scan = m.LaserScan(12.345678901234, -math.pi, 2 * math.pi / 360, 0.15, 12.0, ranges,
                       (rng.random(360) * 47).astype(np.float32), 0.1, "laser")
    back = roundtrip("/scan", scan)
    assert back.ranges_m.dtype == np.float32
    assert np.array_equal(back.ranges_m, scan.ranges_m, equal_nan=True)
    assert np.isinf(back.ranges_m[3]) and np.isnan(back.ranges_m[7])
    assert back.intensities is not None and np.array_equal(back.intensities, scan.intensities)
    for f in ("stamp", "angle_min_rad", "angle_increment_rad", "range_min_m", "range_max_m",
              "scan_time_s", "frame_id"):
        assert getattr(back, f) == getattr(scan, f), f
    body = json.loads(CODEC.encode("/scan", scan)[0][1])
    assert body["ranges"][3] is None and len(body["ranges"]) == 360
    assert body["end_angle"] == pytest.approx(-math.pi + 359 * 2 * math.pi / 360)
    assert body["timestamp"]["sec"] == 1_700_000_012


@pytest.mark.parametrize("msg", [
    m.Imu(1.23456789012345, (0.1, 0.2, 0.3, 0.9273618495495704), (1e-9, -2.5, 3.3333333333333),
          (0.0, -9.80665, 1.0 / 3.0), True, (3, 2, 1, 0)),
    m.WheelEncoders(0.002, (1, None, 1499, 0, 750, None)),
    m.BatteryState(3.003, 7.123456789, False),
    m.ServoCommand(1.0, (1000, -1000, 0, 1, -1, 7), (500, 480, 520, 1000), 50),
    m.OperatorCommand(2.0, "goto", goal=Pose2D(1.0 / 3.0, -2.0, math.nan), source="web",
                      request_id="r1"),
    m.OperatorCommand(2.5, "select_path", path_id=2),
    m.PoseWithCovariance(4.0, Pose2D(1.1, 2.2, 0.3), (0.25, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0,
                                                      0.0, 0.07)),
    m.Twist(5.0, 0.123456789, -0.987654321, source="web"),
    m.NavGoal(6.0, "send", (Pose2D(1.0, 2.0, math.nan), Pose2D(3.0, 4.0, 1.5)), tag="wp 1"),
])
def test_replayed_inputs_round_trip_exactly(msg: Any) -> None:
    topic = {m.Imu: "/imu", m.WheelEncoders: "/wheels", m.BatteryState: "/battery",
             m.ServoCommand: "/servo_cmd", m.OperatorCommand: "/operator",
             m.PoseWithCovariance: "/initialpose", m.Twist: "/cmd_vel_teleop",
             m.NavGoal: "/goal"}[type(msg)]
    assert topic in REPLAY_INPUTS
    back = roundtrip(topic, msg)
    if isinstance(msg, m.PoseWithCovariance):  # positions exact, yaw through a quaternion
        assert (back.pose.x, back.pose.y) == (msg.pose.x, msg.pose.y)
        assert back.pose.yaw == pytest.approx(msg.pose.yaw, abs=1e-15)
        assert (back.stamp, back.covariance) == (msg.stamp, msg.covariance)
        return
    assert repr(back) == repr(msg)  # repr: NaN yaws compare equal


def test_outputs_are_rounded_to_micrometres_but_keep_their_values() -> None:
    odom = m.Odometry(1.0, Pose2D(1.23456789123, -2.0, 0.1234567891), 0.3333333333, 0.0)
    (spec, data), (tf_spec, tf_data) = CODEC.encode("/odom", odom)
    assert b"1.234568" in data and b"1.23456789" not in data
    assert (spec.topic, tf_spec.topic) == ("/odom", "/tf")
    tf = json.loads(tf_data)
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("odom", "base_link")
    back = decode("/odom", data)
    assert back is not None and back[1].pose.x == pytest.approx(1.23456789123, abs=1e-6)


def test_grid_round_trip_and_foxglove_layout() -> None:
    data = np.arange(-1, 101, dtype=np.int8)[np.arange(6 * 4) % 102].reshape(4, 6)
    grid = m.GridMessage(2.0, data, 0.05, Pose2D(-1.0, -2.0, 0.0), version=7, kind="costmap")
    spec, payload = CODEC.encode("/costmap", grid)[0]
    body = json.loads(payload)
    assert spec.schema_name == "foxglove.Grid" and spec.latched
    assert (body["column_count"], body["row_stride"], body["cell_stride"]) == (6, 6, 1)
    assert body["fields"] == [{"name": "cost", "offset": 0, "type": 2}]
    back = decode("/costmap", payload)
    assert back is not None
    assert np.array_equal(back[1].data, data) and back[1].version == 7


def test_map_to_odom_goes_to_tf_and_statics_describe_the_robot() -> None:
    spec, data = CODEC.encode("/tf/map_odom", m.Transform(1.0, Pose2D(1.0, 2.0, 0.5)))[0]
    assert spec.topic == "/tf" and spec.latched
    assert json.loads(data)["child_frame_id"] == "odom"
    assert decode("/tf", data) is None
    statics = CODEC.statics(0.0, {"laser": Pose2D(0.15, 0.08, 0.0)},
                            [(0.3, 0.3), (0.3, -0.3), (-0.3, -0.3)],
                            [("Lobby", Pose2D(2.0, -2.5, math.nan))])
    topics = [s.topic for s, _ in statics]
    assert topics == ["/tf_static", "/scene"]
    scene = json.loads(statics[1][1])
    assert scene["entities"][0]["frame_id"] == "base_link"
    assert scene["entities"][1]["texts"][0]["text"] == "Lobby"


def test_log_records_and_a_corrupt_payload() -> None:
    spec, data = CODEC.log(1.0, 30, "disk nearly full", "curio.record", "x.py", 12)
    assert spec.topic == "/log" and json.loads(data)["level"] == 3
    with pytest.raises(ValueError, match="/imu"):
        decode("/imu", b'{"stamp": 1.0, "orientation_xyzw": "oops"}')
