"""ROS bags in and out, through ``rosbags`` (the optional extra ``curio[ros]``).

**In** (``curio map build --log BAG``, ``curio replay BAG``): rosbag1 (``.bag``) and rosbag2
(its directory with ``metadata.yaml``, or a bare ``.db3`` / ``.mcap`` file) holding
``sensor_msgs/LaserScan`` and ``nav_msgs/Odometry``. :func:`iter_bag` yields them as Curio
messages in time order; :func:`read_bag` pairs each scan with the odometry interpolated at its
stamp, as the same :class:`~curio.estimation.carmen.LogScan` records the CARMEN reader yields.
The scan topic is ``/scan`` when there is one (else the only LaserScan topic), the odometry
``/odom`` likewise; the ``laser`` mount comes from ``/tf_static`` when the bag has it (else it
is the identity). Times are the messages' header stamps (UNIX seconds), the bag's own when a
header has none.

**Out** (``curio export --ros2``): :class:`Ros2BagWriter` writes a rosbag2 directory (MCAP or
sqlite3 storage) with standard ROS 2 messages in CDR, which ``ros2 bag play`` and Nav2 read.

Flight recordings (Curio's own MCAP, profile ``curio``) are read too: :func:`read_bag` of one
yields its ``/scan`` with its ``/odom``, so a map can be built from any recorded run.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, quat_to_yaw, yaw_to_quat
from curio.core.messages import LaserScan, Odometry
from curio.estimation.carmen import LogError, LogScan

__all__ = ["BagMessage", "Ros2BagWriter", "is_bag", "iter_bag", "laser_mount", "read_bag"]

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
INSTALL_HINT = "reading and writing ROS bags needs rosbags: pip install 'curio[ros]'"


def _rosbags() -> Any:
    try:
        import rosbags.highlevel
        import rosbags.rosbag2
        import rosbags.typesys
    except ImportError:
        raise LogError(INSTALL_HINT) from None
    return rosbags


def _mcap_profile(path: Path) -> str | None:
    from curio.record.reader import RecordingError, open_recording

    try:
        return open_recording(path).profile
    except RecordingError:
        return None


def is_bag(path: Path) -> bool:
    """Whether ``path`` is a ROS bag (rosbag1, a rosbag2 directory or file, an MCAP file
    written by ROS rather than by Curio)."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    suffix = path.suffix.lower()
    if suffix in (".bag", ".db3"):
        return True
    return suffix == ".mcap" and _mcap_profile(path) not in (None, "curio")


@dataclass(frozen=True, slots=True)
class BagMessage:
    """One bag message as a Curio message: a scan (``laser`` frame) or odometry."""

    t_s: float
    kind: Literal["scan", "odom"]
    msg: LaserScan | Odometry


def _stamp(header: Any, bag_ns: int) -> float:
    sec, nsec = int(header.stamp.sec), int(header.stamp.nanosec)
    return sec + nsec * 1e-9 if (sec or nsec) else bag_ns * 1e-9


def _pick(conns: list[Any], msgtype: str, preferred: str) -> Any | None:
    found = [c for c in conns if c.msgtype == msgtype]
    named = [c for c in found if c.topic == preferred]
    return (named or found or [None])[0]


def _scan(m: Any, t: float) -> LaserScan:
    ranges = np.asarray(m.ranges, dtype=np.float32).copy()
    inten = np.asarray(m.intensities, dtype=np.float32)
    return LaserScan(t, float(m.angle_min), float(m.angle_increment), float(m.range_min),
                     float(m.range_max), ranges, inten.copy() if len(inten) else None,
                     float(m.scan_time) or 0.1, str(m.header.frame_id) or "laser")


def _odom(m: Any, t: float) -> Odometry:
    p, q = m.pose.pose.position, m.pose.pose.orientation
    yaw = quat_to_yaw((float(q.x), float(q.y), float(q.z), float(q.w)))
    cov = np.asarray(m.pose.covariance, dtype=np.float64).reshape(6, 6)
    cov3 = cov[np.ix_([0, 1, 5], [0, 1, 5])].ravel()
    return Odometry(t, Pose2D(float(p.x), float(p.y), yaw), float(m.twist.twist.linear.x),
                    float(m.twist.twist.angular.z), tuple(float(v) for v in cov3),
                    str(m.header.frame_id) or "odom", str(m.child_frame_id) or "base_link")


def iter_bag(path: Path | str) -> Iterator[BagMessage]:
    """The scans and odometry of a ROS bag, in bag order (see the module docstring).

    Raises:
        LogError: rosbags missing, an unreadable bag, or no LaserScan topic.
    """
    rb = _rosbags()
    p = Path(path)
    default = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
    try:
        with rb.highlevel.AnyReader([p], default_typestore=default) as reader:
            conns = list(reader.connections)
            scan_c = _pick(conns, SCAN_TYPE, "/scan")
            odom_c = _pick(conns, ODOM_TYPE, "/odom")
            if scan_c is None:
                topics = ", ".join(f"{c.topic} ({c.msgtype})" for c in conns) or "none"
                raise LogError(f"{p}: no sensor_msgs/LaserScan topic; topics: {topics}")
            wanted = [c for c in (scan_c, odom_c) if c is not None]
            for conn, bag_ns, raw in reader.messages(connections=wanted):
                m = reader.deserialize(raw, conn.msgtype)
                t = _stamp(m.header, bag_ns)
                if conn is scan_c:
                    yield BagMessage(t, "scan", _scan(m, t))
                else:
                    yield BagMessage(t, "odom", _odom(m, t))
    except LogError:
        raise
    except Exception as exc:  # rosbags raises many kinds for a bad bag
        raise LogError(f"{p}: cannot read the bag ({type(exc).__name__}: {exc})") from None


def laser_mount(path: Path) -> Pose2D:
    """``laser`` in the robot's frame from the bag's ``/tf_static`` (identity if absent)."""
    rb = _rosbags()
    default = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
    try:
        with rb.highlevel.AnyReader([path], default_typestore=default) as reader:
            conns = [c for c in reader.connections
                     if c.msgtype == TF_TYPE and c.topic == "/tf_static"]
            for conn, _, raw in reader.messages(connections=conns):
                for tf in reader.deserialize(raw, conn.msgtype).transforms:
                    if str(tf.child_frame_id) in ("laser", "base_scan", "laser_frame"):
                        tr, q = tf.transform.translation, tf.transform.rotation
                        return Pose2D(float(tr.x), float(tr.y),
                                      quat_to_yaw((q.x, q.y, q.z, q.w)))
    except Exception:  # a bag without usable tf: the identity, as documented
        return Pose2D()
    return Pose2D()


def _interp(ts: list[float], poses: list[Pose2D], t: float) -> Pose2D:
    i = bisect.bisect_left(ts, t)
    if i <= 0:
        return poses[0]
    if i >= len(ts):
        return poses[-1]
    if ts[i] == t:
        return poses[i]
    a, b = poses[i - 1], poses[i]
    f = (t - ts[i - 1]) / (ts[i] - ts[i - 1])
    d = a.inverse() @ b
    return a @ Pose2D(d.x * f, d.y * f, d.yaw * f)


def _decimal(ranges: Any) -> npt.NDArray[np.float64]:
    """float32 ranges as the decimals they stand for (1.39, not 1.3899999856948853): the
    shortest representation that reads back as the same float32, so a log converted to a bag
    maps exactly as the log does."""
    return np.asarray(np.asarray(ranges, dtype=np.float32).astype(str), dtype=np.float64)


def _logscan(scan: LaserScan, odom: Pose2D, laser: Pose2D) -> LogScan:
    r = _decimal(scan.ranges_m)
    r = np.where(np.isfinite(r) & (r >= scan.range_min_m) & (r < scan.range_max_m), r, np.inf)
    return LogScan(scan.stamp, odom, laser, scan.angle_min_rad, scan.angle_increment_rad, r,
                   scan.range_max_m)


def read_bag(path: Path | str) -> Iterator[LogScan]:
    """Scans with the odometry at their stamps, from a ROS bag or a Curio recording.

    Raises:
        LogError: an unreadable input, no scans, or no odometry.
    """
    p = Path(path)
    if not is_bag(p):
        yield from _read_recording(p)
        return
    odom_t: list[float] = []
    odom_p: list[Pose2D] = []
    scans: list[LaserScan] = []
    for item in iter_bag(p):
        if item.kind == "odom":
            assert isinstance(item.msg, Odometry)
            if odom_t and item.t_s < odom_t[-1]:
                continue  # out of order: keep the series monotonic
            odom_t.append(item.t_s)
            odom_p.append(item.msg.pose)
        else:
            assert isinstance(item.msg, LaserScan)
            scans.append(item.msg)
    if not scans:
        raise LogError(f"{p}: the bag holds no scans: nothing to map")
    if not odom_t:
        raise LogError(f"{p}: the bag holds no nav_msgs/Odometry: scans need odometry")
    laser = laser_mount(p)
    for scan in scans:
        yield _logscan(scan, _interp(odom_t, odom_p, scan.stamp), laser)


def _read_recording(p: Path) -> Iterator[LogScan]:
    """``/scan`` and ``/odom`` of a Curio recording (``laser`` mount from its config)."""
    from curio.record.codec import decode
    from curio.record.reader import RecordingError, open_recording

    try:
        rec = open_recording(p)
    except RecordingError as exc:
        raise LogError(str(exc)) from None
    cfg = rec.config_data() or {}
    laser = Pose2D(*cfg.get("robot", {}).get("laser_pose", (0.0, 0.0, 0.0)))
    odom_t: list[float] = []
    odom_p: list[Pose2D] = []
    scans: list[LaserScan] = []
    try:
        for m in rec.messages():
            if m.channel in ("/scan", "/odom"):
                decoded = decode(m.channel, m.data)
                assert decoded is not None
                msg = decoded[1]
                if isinstance(msg, LaserScan):
                    scans.append(msg)
                else:
                    odom_t.append(msg.stamp)
                    odom_p.append(msg.pose)
    except ValueError as exc:
        raise LogError(f"{p}: {exc}") from None
    if not scans or not odom_t:
        raise LogError(f"{p}: the recording holds no /scan with /odom: nothing to map")
    for scan in scans:
        yield _logscan(scan, _interp(odom_t, odom_p, scan.stamp), laser)


class Ros2BagWriter:
    """Writes standard ROS 2 messages (CDR) to a new rosbag2 directory.

    Args:
        path: the bag directory to create (it must not exist).
        storage: ``mcap`` (ROS 2 Iron and later's default) or ``sqlite3``.

    Raises:
        LogError: rosbags missing, or ``path`` exists.
    """

    def __init__(self, path: Path | str, storage: Literal["mcap", "sqlite3"] = "mcap") -> None:
        rb = _rosbags()
        self.path = Path(path)
        if self.path.exists():
            raise LogError(f"{self.path} exists already; give a new directory for the bag")
        self.typestore = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
        plugin = (rb.rosbag2.StoragePlugin.MCAP if storage == "mcap"
                  else rb.rosbag2.StoragePlugin.SQLITE3)
        self._writer = rb.rosbag2.Writer(self.path, version=9, storage_plugin=plugin)
        self._writer.open()
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.T = self.typestore.types

    def write(self, topic: str, msgtype: str, t_s: float, msg: Any) -> None:
        """Serialise ``msg`` (a rosbags message object) to ``topic`` at bag time ``t_s``."""
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
            self._conns[topic] = conn
        t_ns = max(0, round(t_s * 1e9))
        self._writer.write(conn, t_ns, self.typestore.serialize_cdr(msg, msgtype))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    # --- message builders (rosbags message objects) ----------------------------------------
    def header(self, t_s: float, frame_id: str) -> Any:
        """``std_msgs/Header`` at UNIX time ``t_s``."""
        ns = max(0, round(t_s * 1e9))
        stamp = self.T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def pose(self, p: Pose2D) -> Any:
        """``geometry_msgs/Pose`` of a planar pose."""
        x, y, z, w = yaw_to_quat(p.yaw if math.isfinite(p.yaw) else 0.0)
        return self.T["geometry_msgs/msg/Pose"](
            position=self.T["geometry_msgs/msg/Point"](x=p.x, y=p.y, z=0.0),
            orientation=self.T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))

    def covariance6(self, cov3: tuple[float, ...]) -> Any:
        """A 6×6 row-major covariance from Curio's 3×3 of (x, y, yaw)."""
        out = np.zeros((6, 6))
        c = np.asarray(cov3, dtype=np.float64).reshape(3, 3)
        idx = [0, 1, 5]
        out[np.ix_(idx, idx)] = c
        return out.ravel()

    def scan(self, t_s: float, scan: LaserScan) -> None:
        """``/scan`` as ``sensor_msgs/LaserScan``."""
        n = len(scan.ranges_m)
        inten = (np.asarray(scan.intensities, dtype=np.float32) if scan.intensities is not None
                 else np.zeros(0, dtype=np.float32))
        msg = self.T[SCAN_TYPE](
            header=self.header(t_s, scan.frame_id), angle_min=scan.angle_min_rad,
            angle_max=scan.angle_min_rad + (n - 1) * scan.angle_increment_rad,
            angle_increment=scan.angle_increment_rad,
            time_increment=scan.scan_time_s / max(1, n), scan_time=scan.scan_time_s,
            range_min=scan.range_min_m, range_max=scan.range_max_m,
            ranges=np.asarray(scan.ranges_m, dtype=np.float32), intensities=inten)
        self.write("/scan", SCAN_TYPE, t_s, msg)

    def odometry(self, topic: str, t_s: float, odom: Odometry) -> None:
        """``nav_msgs/Odometry``."""
        twist = self.T["geometry_msgs/msg/Twist"](
            linear=self.T["geometry_msgs/msg/Vector3"](x=odom.linear_mps, y=0.0, z=0.0),
            angular=self.T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=odom.angular_radps))
        msg = self.T[ODOM_TYPE](
            header=self.header(t_s, odom.frame_id), child_frame_id=odom.child_frame_id,
            pose=self.T["geometry_msgs/msg/PoseWithCovariance"](
                pose=self.pose(odom.pose), covariance=self.covariance6(odom.covariance)),
            twist=self.T["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.zeros(36)))
        self.write(topic, ODOM_TYPE, t_s, msg)

    def transforms(self, topic: str, t_s: float,
                   frames: list[tuple[str, str, Pose2D]]) -> None:
        """``tf2_msgs/TFMessage`` of ``(parent, child, pose of child in parent)``."""
        tfs = []
        for parent, child, p in frames:
            x, y, z, w = yaw_to_quat(p.yaw)
            tfs.append(self.T["geometry_msgs/msg/TransformStamped"](
                header=self.header(t_s, parent), child_frame_id=child,
                transform=self.T["geometry_msgs/msg/Transform"](
                    translation=self.T["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=0.0),
                    rotation=self.T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))))
        self.write(topic, TF_TYPE, t_s, self.T[TF_TYPE](transforms=tfs))

    def close(self) -> None:
        """Finish the bag (writes ``metadata.yaml``)."""
        self._writer.close()
