"""The rover's ROS 2 publisher: ``/scan``, ``/odom``, ``/tf`` (and ``/tf_static``) and ``/map``
as ROS 2 CDR over the fleet's Zenoh session, named the way ``rmw_zenoh`` names them.

Topics are in the namespace ``fleet.ros2.namespace`` (default ``/<rover>``), so several rovers
share one ROS graph: ``/r1/scan``, ``/r1/odom``, ``/r1/tf``, ``/r1/tf_static``, ``/r1/map``
(remap ``/tf`` to ``/r1/tf`` in RViz, or set ``frame_prefix`` and a namespace of ``""``). The
node is ``curio`` in that namespace; it holds the liveliness tokens of itself and of its five
publishers, declared once the session is open (they contain its Zenoh id).

* ``scan`` (``sensor_msgs/msg/LaserScan``, best effort, depth 5) at ``scan_rate_hz``;
* ``odom`` (``nav_msgs/msg/Odometry``: ``odom`` → ``base_link`` from the EKF, the 3×3
  covariance placed in the 6×6 one) at ``odom_rate_hz``;
* ``tf`` (``tf2_msgs/msg/TFMessage``: ``map`` → ``odom`` and ``odom`` → ``base_link``) at
  ``tf_rate_hz``; ``tf_static`` (``base_link`` → ``laser`` and ``imu_link``, transient local);
* ``map`` (``nav_msgs/msg/OccupancyGrid``, transient local) whenever it changes, and every
  30 s for subscribers that do not ask for history.

Stamps are the rover's wall clock at the message's time. Nothing here waits on the network.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import FleetRos2Config
from curio.core.geometry import Pose2D, yaw_to_quat
from curio.core.messages import GridMessage, LaserScan, Odometry, Transform
from curio.core.topics import MAP, MAP_TO_ODOM, ODOM, SCAN
from curio.fleet.ros2.msgs import serialize
from curio.fleet.ros2.rmw import (
    BEST_EFFORT,
    TRANSIENT_LOCAL,
    Qos,
    attachment,
    gid_of,
    node_token,
    publisher_token,
    topic_keyexpr,
)
from curio.fleet.transport import Transport
from curio.robot import RobotModel

__all__ = ["TOPICS", "Ros2Publisher", "grid_msg", "odometry_msg", "scan_msg", "tf_msg"]

log = logging.getLogger("curio.fleet.ros2")

NODE = "curio"
MAP_REPEAT_S = 30.0
# topic -> (type, QoS)
TOPICS: dict[str, tuple[str, Qos]] = {
    "scan": ("sensor_msgs/msg/LaserScan", Qos(reliability=BEST_EFFORT, depth=5)),
    "odom": ("nav_msgs/msg/Odometry", Qos(depth=10)),
    "tf": ("tf2_msgs/msg/TFMessage", Qos(depth=100)),
    "tf_static": ("tf2_msgs/msg/TFMessage", Qos(durability=TRANSIENT_LOCAL, depth=1)),
    "map": ("nav_msgs/msg/OccupancyGrid", Qos(durability=TRANSIENT_LOCAL, depth=1)),
}
PLANAR_VARIANCE = 1e-6  # z, roll and pitch of a rover on a floor


def ros_time(wall_s: float) -> dict[str, int]:
    """``builtin_interfaces/Time`` of a UNIX time."""
    sec = math.floor(wall_s)
    return {"sec": int(sec), "nanosec": min(999_999_999, round((wall_s - sec) * 1e9))}


def _pose(p: Pose2D) -> dict[str, Any]:
    x, y, z, w = yaw_to_quat(p.yaw)
    return {"position": {"x": p.x, "y": p.y, "z": 0.0},
            "orientation": {"x": x, "y": y, "z": z, "w": w}}


def _transform(stamp_wall_s: float, parent: str, child: str, p: Pose2D) -> dict[str, Any]:
    x, y, z, w = yaw_to_quat(p.yaw)
    return {"header": {"stamp": ros_time(stamp_wall_s), "frame_id": parent},
            "child_frame_id": child,
            "transform": {"translation": {"x": p.x, "y": p.y, "z": 0.0},
                          "rotation": {"x": x, "y": y, "z": z, "w": w}}}


def _cov6(cov3: tuple[float, ...]) -> list[float]:
    """The 6×6 covariance (x, y, z, roll, pitch, yaw) of a 3×3 one (x, y, yaw)."""
    out = [0.0] * 36
    idx = (0, 1, 5)
    for i in range(3):
        for j in range(3):
            out[idx[i] * 6 + idx[j]] = float(cov3[i * 3 + j])
    for k in (2, 3, 4):
        out[k * 6 + k] = PLANAR_VARIANCE
    return out


def scan_msg(scan: LaserScan, stamp_wall_s: float, frame: str) -> bytes:
    """``sensor_msgs/msg/LaserScan`` CDR of a Curio scan."""
    n = len(scan.ranges_m)
    return serialize("sensor_msgs/msg/LaserScan", {
        "header": {"stamp": ros_time(stamp_wall_s), "frame_id": frame},
        "angle_min": scan.angle_min_rad,
        "angle_max": scan.angle_min_rad + scan.angle_increment_rad * max(0, n - 1),
        "angle_increment": scan.angle_increment_rad,
        "time_increment": scan.scan_time_s / n if n else 0.0, "scan_time": scan.scan_time_s,
        "range_min": scan.range_min_m, "range_max": scan.range_max_m,
        "ranges": scan.ranges_m,
        "intensities": scan.intensities if scan.intensities is not None else []})


def odometry_msg(odom: Odometry, stamp_wall_s: float, prefix: str) -> bytes:
    """``nav_msgs/msg/Odometry`` CDR of the EKF's ``odom`` → ``base_link``."""
    return serialize("nav_msgs/msg/Odometry", {
        "header": {"stamp": ros_time(stamp_wall_s), "frame_id": prefix + odom.frame_id},
        "child_frame_id": prefix + odom.child_frame_id,
        "pose": {"pose": _pose(odom.pose), "covariance": _cov6(odom.covariance)},
        "twist": {"twist": {"linear": {"x": odom.linear_mps, "y": 0.0, "z": 0.0},
                            "angular": {"x": 0.0, "y": 0.0, "z": odom.angular_radps}},
                  "covariance": _cov6((0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01))}})


def tf_msg(transforms: list[tuple[float, str, str, Pose2D]]) -> bytes:
    """``tf2_msgs/msg/TFMessage`` CDR of ``(stamp, parent, child, pose)`` transforms."""
    return serialize("tf2_msgs/msg/TFMessage", {"transforms": [
        _transform(t, parent, child, p) for t, parent, child, p in transforms]})


def grid_msg(grid: GridMessage, stamp_wall_s: float, prefix: str) -> bytes:
    """``nav_msgs/msg/OccupancyGrid`` CDR of a Curio map (row 0 at the bottom, as in ROS)."""
    h, w = grid.data.shape
    return serialize("nav_msgs/msg/OccupancyGrid", {
        "header": {"stamp": ros_time(stamp_wall_s), "frame_id": prefix + grid.frame_id},
        "info": {"map_load_time": ros_time(stamp_wall_s), "resolution": grid.resolution_m,
                 "width": w, "height": h, "origin": _pose(grid.origin)},
        "data": grid.data.reshape(-1)})


class Ros2Publisher:
    """The rover's ROS 2 part (see the module docstring).

    Args:
        cfg: ``fleet.ros2``.
        rover: the rover's name (the default namespace).
        bus, clock: injected.
        transport: the fleet's link (a Zenoh session).
        robot: the robot model (the static transforms).
    """

    def __init__(self, cfg: FleetRos2Config, rover: str, bus: Bus, clock: Clock,
                 transport: Transport, robot: RobotModel) -> None:
        self.cfg = cfg
        self.namespace = cfg.namespace if cfg.namespace else f"/{rover}"
        self.prefix = cfg.frame_prefix
        self.bus = bus
        self.clock = clock
        self.transport = transport
        self.robot = robot
        self.keys = {t: topic_keyexpr(cfg.domain_id, self.namespace, t, ty)
                     for t, (ty, _) in TOPICS.items()}
        self._gid: dict[str, bytes] = {}
        self._seq: dict[str, int] = dict.fromkeys(TOPICS, 0)
        self._last: dict[str, Any] = {}
        self.tokens: list[str] = []
        self.published: dict[str, int] = dict.fromkeys(TOPICS, 0)

    def declare(self) -> None:
        """Declare the transient-local caches (before the link opens)."""
        for topic, (_, qos) in TOPICS.items():
            if qos.durability == TRANSIENT_LOCAL:
                self.transport.declare_cache(self.keys[topic], qos.depth)

    def _declare_tokens(self) -> None:
        zid = getattr(self.transport, "zid", "") or "0"
        d = self.cfg.domain_id
        self.tokens = [node_token(d, zid, 0, self.namespace, NODE)]
        for entity, (topic, (ty, qos)) in enumerate(TOPICS.items(), start=1):
            token = publisher_token(d, zid, 0, entity, self.namespace, NODE, topic, ty, qos)
            self._gid[topic] = gid_of(token)
            self.tokens.append(token)
        for token in self.tokens:
            self.transport.declare_token(token)

    def _put(self, topic: str, payload: bytes, stamp_wall_s: float) -> None:
        self._seq[topic] += 1
        att = attachment(self._seq[topic], int(stamp_wall_s * 1e9),
                         self._gid.get(topic, bytes(16)))
        self.transport.put(self.keys[topic], payload, attachment=att)
        self.published[topic] += 1

    def _wall(self, stamp: float) -> float:
        return self.clock.wall_time() - (self.clock.now() - stamp)

    def step(self, now: float, due: dict[str, float]) -> None:
        """Publish what is due at clock time ``now`` (``due``: next times per topic)."""
        cfg, p = self.cfg, self.prefix
        scan = self.bus.latest(SCAN)
        if now >= due["scan"] and scan is not None and scan is not self._last.get("scan"):
            due["scan"] = now + 1.0 / cfg.scan_rate_hz
            self._last["scan"] = scan
            t = self._wall(scan.stamp)
            self._put("scan", scan_msg(scan, t, p + scan.frame_id), t)
        odom = self.bus.latest(ODOM)
        if now >= due["odom"] and odom is not None:
            due["odom"] = now + 1.0 / cfg.odom_rate_hz
            t = self._wall(odom.stamp)
            self._put("odom", odometry_msg(odom, t, p), t)
        if now >= due["tf"]:
            due["tf"] = now + 1.0 / cfg.tf_rate_hz
            self._tf(odom, self.bus.latest(MAP_TO_ODOM))
        grid = self.bus.latest(MAP)
        if grid is not None and (grid is not self._last.get("map") or now >= due["map"]):
            due["map"] = now + MAP_REPEAT_S
            self._last["map"] = grid
            t = self.clock.wall_time()
            self._put("map", grid_msg(grid, t, p), t)

    def _tf(self, odom: Odometry | None, correction: Transform | None) -> None:
        p = self.prefix
        transforms = []
        if correction is not None:
            transforms.append((self._wall(correction.stamp), p + correction.frame_id,
                               p + correction.child_frame_id, correction.transform))
        if odom is not None:
            transforms.append((self._wall(odom.stamp), p + odom.frame_id,
                               p + odom.child_frame_id, odom.pose))
        if transforms:
            self._put("tf", tf_msg(transforms), transforms[-1][0])

    def _static(self) -> None:
        t = self.clock.wall_time()
        p = self.prefix
        self._put("tf_static", tf_msg([(t, p + "base_link", p + "laser", self.robot.laser_in_base),
                                       (t, p + "base_link", p + "imu_link",
                                        self.robot.imu_in_base)]), t)

    async def run(self) -> None:
        """Wait for the link, declare the graph, then publish until cancelled."""
        await self.clock.wait_until(lambda: self.transport.connected, math.inf, 0.2)
        self._declare_tokens()
        self._static()
        due = dict.fromkeys(("scan", "odom", "tf", "map"), 0.0)
        period = 1.0 / max(self.cfg.scan_rate_hz, self.cfg.odom_rate_hz, self.cfg.tf_rate_hz)
        async for now in self.clock.every(period, phase_s=0.019):
            self.step(now, due)
