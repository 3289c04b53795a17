"""ROS bags in and out: the CSAIL log as a rosbag2 maps the same as the CARMEN log; rosbag1
and sqlite3 bags read; ``curio export --ros2`` writes standard ROS 2 messages that ``rosbags``
reads back; ``curio replay`` localises a bag."""

from __future__ import annotations

import io
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from curio.commands import export, replay
from curio.commands.map import main as map_main
from curio.core.config import REPO_ROOT
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, Odometry
from curio.estimation.carmen import LogError, LogScan, read_carmen
from curio.estimation.logs import read_log
from curio.estimation.mapping import build_map_from_log
from curio.estimation.maps import OccupancyGrid, load_map
from curio.estimation.rosbag import Ros2BagWriter, is_bag

rosbags = pytest.importorskip("rosbags", reason="the curio[ros] extra (rosbags) is missing")

HEAD = 300  # scans of the CSAIL log: enough for a few rooms, a few seconds to map


def to_bag(scans: list[LogScan], path: Path, storage: str = "mcap") -> None:
    """What a ROS user would have: /scan, /odom and the laser mount in /tf_static."""
    w = Ros2BagWriter(path, storage)  # type: ignore[arg-type]
    w.transforms("/tf_static", scans[0].stamp, [("base_link", "laser", scans[0].laser_pose)])
    for s in scans:
        w.odometry("/odom", s.stamp, Odometry(s.stamp, s.odom))
        w.scan(s.stamp, LaserScan(s.stamp, s.angle_min_rad, s.angle_increment_rad, 0.0,
                                  s.range_max_m, np.asarray(s.ranges_m, dtype=np.float32)))
    w.close()


def occupied_points(g: OccupancyGrid) -> np.ndarray:
    rows, cols = np.nonzero(g.occupied_mask())
    return np.stack([g.origin.x + (cols + 0.5) * g.resolution_m,
                     g.origin.y + (rows + 0.5) * g.resolution_m], axis=1)


def test_the_csail_log_as_a_rosbag2_maps_like_the_carmen_log(mit_csail_log: Path,
                                                             tmp_path: Path) -> None:
    carmen = list(itertools.islice(read_carmen(mit_csail_log), HEAD))
    to_bag(carmen, tmp_path / "csail")
    assert is_bag(tmp_path / "csail")
    bag = list(read_log(tmp_path / "csail"))
    # The bag carries the same scans: ranges exactly (float32 decimals), the rest to the
    # precision ROS's fields allow (float32 angles, quaternions).
    assert len(bag) == len(carmen)
    for a, b in zip(carmen, bag, strict=True):
        assert b.stamp == pytest.approx(a.stamp, abs=1e-6)
        assert np.array_equal(a.ranges_m, b.ranges_m)
        assert b.odom.distance_to(a.odom) < 1e-9 and abs(b.odom.yaw - a.odom.yaw) < 1e-12
        assert b.angle_min_rad == pytest.approx(a.angle_min_rad, abs=1e-7)
        assert b.angle_increment_rad == pytest.approx(a.angle_increment_rad, rel=1e-7)
        assert b.laser_pose.distance_to(a.laser_pose) < 1e-9
    map_a = build_map_from_log(carmen)
    map_b = build_map_from_log(bag)
    pa, pb = occupied_points(map_a.occupancy()), occupied_points(map_b.occupancy())
    assert len(pb) == pytest.approx(len(pa), rel=0.05)
    # Every wall of one map is a wall of the other, give or take one 5 cm cell.
    near_ab = (cKDTree(pb).query(pa)[0] <= 0.051).mean()
    near_ba = (cKDTree(pa).query(pb)[0] <= 0.051).mean()
    assert near_ab > 0.9 and near_ba > 0.9, (near_ab, near_ba)
    ta = np.array([p.as_tuple()[:2] for _, p in map_a.trajectory])
    tb = np.array([p.as_tuple()[:2] for _, p in map_b.trajectory])
    assert np.linalg.norm(ta - tb, axis=1).max() < 0.15


def test_rosbag1_and_sqlite3_bags_read(mit_csail_log: Path, tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.typesys import Stores, get_typestore

    carmen = list(itertools.islice(read_carmen(mit_csail_log), 20))
    to_bag(carmen, tmp_path / "sq", "sqlite3")
    assert len(list(read_log(tmp_path / "sq"))) == 20
    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    with Writer1(tmp_path / "one.bag") as w:
        scan_c = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        odom_c = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        for i, s in enumerate(carmen):
            sec, nsec = int(s.stamp), round((s.stamp % 1) * 1e9) % 10**9
            hdr = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](
                sec=sec, nanosec=nsec), frame_id="laser")
            scan = T["sensor_msgs/msg/LaserScan"](
                header=hdr, angle_min=s.angle_min_rad, angle_max=-s.angle_min_rad,
                angle_increment=s.angle_increment_rad, time_increment=0.0, scan_time=0.1,
                range_min=0.0, range_max=s.range_max_m,
                ranges=np.asarray(s.ranges_m, dtype=np.float32), intensities=np.zeros(0))
            q = (0.0, 0.0, math.sin(s.odom.yaw / 2), math.cos(s.odom.yaw / 2))
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=s.odom.x, y=s.odom.y, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
            vec = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            odom = T["nav_msgs/msg/Odometry"](
                header=hdr, child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                                covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=vec, angular=vec),
                    covariance=np.zeros(36)))
            t_ns = sec * 10**9 + nsec
            w.write(odom_c, t_ns, store.serialize_ros1(odom, "nav_msgs/msg/Odometry"))
            w.write(scan_c, t_ns, store.serialize_ros1(scan, "sensor_msgs/msg/LaserScan"))
    got = list(read_log(tmp_path / "one.bag"))
    assert len(got) == 20 and got[5].odom.distance_to(carmen[5].odom) < 1e-9
    out, err = io.StringIO(), io.StringIO()
    assert map_main(["build", "--log", str(tmp_path / "one.bag"), "--out",
                     str(tmp_path / "one.yaml"), "--quiet"], out, err) == 0, err.getvalue()
    assert load_map(tmp_path / "one.yaml").occupied_mask().sum() > 50


def test_a_bag_without_scans_is_one_clear_error(tmp_path: Path) -> None:
    w = Ros2BagWriter(tmp_path / "odom-only")
    w.odometry("/odom", 1.0, Odometry(1.0, Pose2D()))
    w.close()
    with pytest.raises(LogError, match="no sensor_msgs/LaserScan topic; topics: /odom"):
        list(read_log(tmp_path / "odom-only"))
    err = io.StringIO()
    assert map_main(["build", "--log", str(tmp_path / "odom-only"), "--out",
                     str(tmp_path / "x.yaml")], io.StringIO(), err) == 2
    assert "LaserScan" in err.getvalue()


@pytest.mark.slow
def test_export_a_recorded_run_to_ros2_and_replay_the_bag(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    from curio.cli import main as cli_main

    rec = tmp_path / "goto.mcap"
    assert cli_main(["sim", "goto", "--goal", "3,1", "--record", str(rec), "--set",
                     f'data_dir="{tmp_path / "data"}"']) == 0
    out, err = io.StringIO(), io.StringIO()
    assert export.main(["--ros2", str(rec), str(tmp_path / "bag")], out, err) == 0, \
        err.getvalue()
    assert export.main(["--ros2", str(rec), str(tmp_path / "bag")], out, err) == 2  # exists
    with AnyReader([tmp_path / "bag"]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/scan"] == "sensor_msgs/msg/LaserScan"
        assert types["/odom"] == "nav_msgs/msg/Odometry"
        assert types["/tf"] == types["/tf_static"] == "tf2_msgs/msg/TFMessage"
        assert types["/map"] == "nav_msgs/msg/OccupancyGrid"
        assert types["/cmd_vel"] == "geometry_msgs/msg/Twist"
        scans = [c for c in reader.connections if c.topic == "/scan"]
        first = next(reader.messages(connections=scans))
        msg = reader.deserialize(first[2], first[0].msgtype)
        assert len(msg.ranges) == 360 and msg.header.frame_id == "laser"
        assert msg.header.stamp.sec > 1_600_000_000  # UNIX time
    out = io.StringIO()
    code = replay.main([str(tmp_path / "bag"), "--map",
                        str(REPO_ROOT / "maps" / "curio_building.yaml"), "--report",
                        str(tmp_path / "r.json")], out, io.StringIO())
    assert code == 0, out.getvalue()
    rep = json.loads((tmp_path / "r.json").read_text())
    states = rep["localization_states"]
    assert states["ok"] / sum(states.values()) > 0.9, states
    final = rep["final_pose"]
    assert math.hypot(final["x"] - 3.0, final["y"] - 1.0) < 0.3  # where the goto went
