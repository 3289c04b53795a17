"""``curio export``: a recording in another format.

Usage::

    curio export --ros2 FILE.mcap OUT [--storage mcap|sqlite3]

``--ros2`` writes a rosbag2 directory ``OUT`` (``metadata.yaml`` and the storage file; MCAP by
default, as ROS 2 Iron and later record) with standard ROS 2 messages in CDR, so ``ros2 bag
play`` and Nav2 use Curio's data (needs ``curio[ros]``):

=================  ===================================================
``/scan``          ``sensor_msgs/msg/LaserScan`` (``laser``)
``/odom``          ``nav_msgs/msg/Odometry`` (the EKF: ``odom`` → ``base_link``)
``/wheel_odom``    ``nav_msgs/msg/Odometry`` (wheels alone)
``/imu``           ``sensor_msgs/msg/Imu`` (``imu_link``)
``/tf``            ``tf2_msgs/msg/TFMessage`` (``map`` → ``odom`` → ``base_link``)
``/tf_static``     ``tf2_msgs/msg/TFMessage`` (``base_link`` → ``laser``, ``imu_link``)
``/pose``          ``geometry_msgs/msg/PoseWithCovarianceStamped`` (``map``, like AMCL's)
``/initialpose``   ``geometry_msgs/msg/PoseWithCovarianceStamped``
``/plan``          ``nav_msgs/msg/Path``
``/map``           ``nav_msgs/msg/OccupancyGrid``
``/cmd_vel``       ``geometry_msgs/msg/Twist`` (also ``/cmd_vel_nav``, ``/cmd_vel_teleop``)
=================  ===================================================

Header stamps and bag times are UNIX times (the recording's wall clock). Maps stay map_server
YAML/PGM files (``curio map``). Exit codes: 0 written, 2 bad arguments or input.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from curio.commands.common import run_command
from curio.core.errors import SetupError
from curio.core.geometry import Pose2D, quat_to_yaw
from curio.core.messages import (
    GridMessage,
    Imu,
    LaserScan,
    Odometry,
    PoseWithCovariance,
    Twist,
)
from curio.core.messages import (
    Path as PathMsg,
)
from curio.estimation.rosbag import Ros2BagWriter
from curio.record.codec import decode
from curio.record.reader import RecordedMessage, open_recording

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="curio export", description="Convert a recording.")
    p.add_argument("--ros2", action="store_true", required=True,
                   help="write a ROS 2 bag (rosbag2 directory, CDR messages)")
    p.add_argument("file", type=Path, help="a Curio recording (.mcap)")
    p.add_argument("out", type=Path, help="the bag directory to create")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="the bag's storage (default mcap)")
    return p


class _Exporter:
    """Turns recorded messages into ROS 2 messages on a :class:`Ros2BagWriter`."""

    def __init__(self, writer: Ros2BagWriter, offset_s: float) -> None:
        self.w = writer
        self.offset = offset_s
        self.T = writer.T
        self._handlers: dict[str, Callable[[float, Any], None]] = {
            "/scan": self.scan, "/odom": self.odom, "/wheel_odom": self.odom,
            "/imu": self.imu, "/pose": self.pose, "/initialpose": self.pose, "/plan": self.plan,
            "/map": self.grid, "/cmd_vel": self.twist, "/cmd_vel_nav": self.twist,
            "/cmd_vel_teleop": self.twist}
        self._topic = ""

    def add(self, m: RecordedMessage) -> None:
        """Export one recorded message (channels without a ROS 2 form are skipped)."""
        t = m.log_ns / 1e9
        if m.channel in ("/tf", "/tf_static"):
            self.tf(m.channel, t, json.loads(m.data))
            return
        handler = self._handlers.get(m.channel)
        if handler is None:
            return
        decoded = decode(m.channel, m.data)
        if decoded is not None:
            self._topic = m.channel
            handler(t, decoded[1])

    def tf(self, topic: str, t: float, body: dict[str, Any]) -> None:
        """A ``foxglove.FrameTransform`` as a one-transform ``TFMessage``."""
        tr, q = body["translation"], body["rotation"]
        pose = Pose2D(tr["x"], tr["y"], quat_to_yaw((q["x"], q["y"], q["z"], q["w"])))
        self.w.transforms(topic, t, [(body["parent_frame_id"], body["child_frame_id"], pose)])

    def scan(self, t: float, msg: LaserScan) -> None:
        """``sensor_msgs/LaserScan`` (stamped with the scan's own time)."""
        self.w.scan(msg.stamp + self.offset, msg)

    def odom(self, t: float, msg: Odometry) -> None:
        """``nav_msgs/Odometry`` (stamped with its own time)."""
        self.w.odometry(self._topic, msg.stamp + self.offset, msg)

    def imu(self, t: float, msg: Imu) -> None:
        """``sensor_msgs/Imu`` (orientation covariance -1 when the orientation is not valid)."""
        v3 = self.T["geometry_msgs/msg/Vector3"]
        qx, qy, qz, qw = msg.orientation_xyzw
        ocov = np.zeros(9) if msg.orientation_valid else np.array([-1.0] + [0.0] * 8)
        out = self.T["sensor_msgs/msg/Imu"](
            header=self.w.header(msg.stamp + self.offset, msg.frame_id),
            orientation=self.T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            orientation_covariance=ocov,
            angular_velocity=v3(x=msg.angular_velocity_radps[0], y=msg.angular_velocity_radps[1],
                                z=msg.angular_velocity_radps[2]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=v3(x=msg.linear_acceleration_mps2[0],
                                   y=msg.linear_acceleration_mps2[1],
                                   z=msg.linear_acceleration_mps2[2]),
            linear_acceleration_covariance=np.zeros(9))
        self.w.write("/imu", "sensor_msgs/msg/Imu", t, out)

    def pose(self, t: float, msg: PoseWithCovariance) -> None:
        """``geometry_msgs/PoseWithCovarianceStamped``."""
        kind = "geometry_msgs/msg/PoseWithCovarianceStamped"
        out = self.T[kind](
            header=self.w.header(msg.stamp + self.offset, msg.frame_id),
            pose=self.T["geometry_msgs/msg/PoseWithCovariance"](
                pose=self.w.pose(msg.pose), covariance=self.w.covariance6(msg.covariance)))
        self.w.write(self._topic, kind, t, out)

    def plan(self, t: float, msg: PathMsg) -> None:
        """``nav_msgs/Path``."""
        stamp = msg.stamp + self.offset
        poses = [self.T["geometry_msgs/msg/PoseStamped"](
            header=self.w.header(stamp, msg.frame_id), pose=self.w.pose(p)) for p in msg.poses]
        out = self.T["nav_msgs/msg/Path"](header=self.w.header(stamp, msg.frame_id),
                                          poses=poses)
        self.w.write("/plan", "nav_msgs/msg/Path", t, out)

    def grid(self, t: float, msg: GridMessage) -> None:
        """``nav_msgs/OccupancyGrid`` (rows from the bottom, as in ROS)."""
        h, w = msg.data.shape
        stamp = self.w.header(msg.stamp + self.offset, msg.frame_id)
        info = self.T["nav_msgs/msg/MapMetaData"](
            map_load_time=stamp.stamp, resolution=msg.resolution_m, width=w, height=h,
            origin=self.w.pose(msg.origin))
        out = self.T["nav_msgs/msg/OccupancyGrid"](
            header=stamp, info=info, data=np.ascontiguousarray(msg.data, dtype=np.int8).ravel())
        self.w.write("/map", "nav_msgs/msg/OccupancyGrid", t, out)

    def twist(self, t: float, msg: Twist) -> None:
        """``geometry_msgs/Twist`` (ROS's ``cmd_vel`` carries no stamp)."""
        v3 = self.T["geometry_msgs/msg/Vector3"]
        out = self.T["geometry_msgs/msg/Twist"](
            linear=v3(x=msg.linear_mps, y=0.0, z=0.0),
            angular=v3(x=0.0, y=0.0, z=msg.angular_radps))
        self.w.write(self._topic, "geometry_msgs/msg/Twist", t, out)


def export_ros2(src: Path, out: Path, storage: str = "mcap") -> dict[str, int]:
    """Write the ROS 2 bag ``out`` from the recording ``src``; return the counts per topic.

    Raises:
        SetupError: the recording is unreadable or not Curio's; LogError: no rosbags, or
            ``out`` exists.
    """
    rec = open_recording(src)
    if not rec.curio:
        raise SetupError(f"{src}: not a Curio recording (MCAP profile {rec.profile!r})")
    offset = float(rec.curio.get("time_offset_s", "0"))
    if not math.isfinite(offset):
        raise SetupError(f"{src}: a bad time_offset_s in its metadata")
    writer = Ros2BagWriter(out, "sqlite3" if storage == "sqlite3" else "mcap")
    exporter = _Exporter(writer, offset)
    try:
        for m in rec.messages():
            exporter.add(m)
    except ValueError as exc:
        raise SetupError(f"{src}: {exc}") from None
    finally:
        writer.close()
    return dict(writer.counts)


def _run(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    counts = export_ros2(args.file, args.out, args.storage)
    out.write(f"wrote the ROS 2 bag {args.out} ({args.storage}): "
              + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + "\n")
    return 0


def main(argv: list[str] | None = None, out: TextIO | None = None,
         err: TextIO | None = None) -> int:
    """Run ``curio export`` with ``argv`` (without the ``export`` word); return the exit code."""
    return run_command("export", _parser(), argv, out, err, _run)
