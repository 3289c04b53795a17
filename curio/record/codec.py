"""Bus messages ↔ recorded channels: the channel table, the encoders and the decoders.

Channel names mirror ROS: a bus topic is recorded under its own name (``/scan``, ``/odom``,
``/plan``, ``/cmd_vel`` ...), except the ``map → odom`` correction (bus ``/tf/map_odom``),
which goes to ``/tf`` with the ``odom → base_link`` transform of every ``/odom`` — so
Foxglove's 3D panel walks ``map → odom → base_link``; the fixed mounts (``base_link → laser``,
``base_link → imu_link``) go to ``/tf_static``. Python log records go to ``/log``; the
footprint, the configured waypoints and tour stops to ``/scene``.

Foxglove's well-known types (``curio/record/schemas.py``): ``/scan`` LaserScan; ``/pose`` and
``/initialpose`` PoseInFrame; ``/tf``, ``/tf_static`` FrameTransform; ``/map``, ``/costmap``,
``/local_costmap`` Grid; ``/plan``, ``/local_plan`` PosesInFrame; ``/obstacles``, ``/scene``
SceneUpdate; ``/log`` Log. Every other topic is its Curio message as JSON (``curio.<Class>``).

Times: a message's ``timestamp`` is its ``stamp`` plus ``time_offset_s`` (the clock's
``wall_time() - now()`` when the recording started), so Foxglove shows wall-clock times.

Exactness: a replay must rebuild the very message that was published. Curio JSON is exact
(floats round-trip); scans keep every float32 range exactly (shortest repr) with ``null`` for
no return and the NaN beams listed in ``curio.nan``; the Foxglove-typed channels a replay reads
carry the fields Foxglove's type lacks under ``curio`` (the stamp, a scan's range limits, a
pose's covariance); positions are exact, a yaw comes back from its quaternion to about 1e-16
rad. ``/tf`` and ``/obstacles`` are drawn, not replayed. Only what a replay publishes again
(``REPLAY_INPUTS``) must be exact: every other channel is rounded to ``OUTPUT_DIGITS``
decimals (micrometres, microradians), which keeps the files small.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import json
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, Union

import numpy as np

from curio.core import messages as m
from curio.core.bus import Topic
from curio.core.geometry import Pose2D, yaw_to_quat
from curio.core.jsonable import to_jsonable
from curio.core.topics import ALL_TOPICS, MAP_TO_ODOM
from curio.record.schemas import FOXGLOVE_SCHEMAS, curio_schema, schema_bytes

__all__ = [
    "OUTPUT_DIGITS",
    "REPLAY_INPUTS",
    "ChannelSpec",
    "Codec",
    "Encoded",
    "decode",
    "from_jsonable",
    "primary_channel",
    "to_ns",
]

Json = dict[str, Any]
LOG_LEVELS = {10: 1, 20: 2, 30: 3, 40: 4, 50: 5}  # Python logging -> foxglove.Log level
# What a replay publishes again: recorded exactly. Every other channel is rounded to
# OUTPUT_DIGITS decimals (micrometres, microradians, microseconds), which shortens the JSON.
REPLAY_INPUTS = frozenset({"/scan", "/wheels", "/imu", "/battery", "/servo_cmd", "/operator",
                           "/initialpose", "/cmd_vel_teleop", "/goal"})
OUTPUT_DIGITS = 6


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """One recorded channel: its topic, schema and whether its last message is state
    (re-written at the start of every new file so each file stands on its own). Two specs may
    share a topic (``/tf``: the latched ``map → odom`` and the streamed ``odom → base_link``)."""

    topic: str
    schema_name: str
    schema: bytes
    latched: bool = False


Encoded = tuple[ChannelSpec, bytes]


@functools.cache
def _spec(topic: str, schema_name: str, latched: bool) -> ChannelSpec:
    schema = FOXGLOVE_SCHEMAS.get(schema_name)
    if schema is None:
        cls = getattr(m, schema_name.removeprefix("curio."))
        schema = curio_schema(cls)
    return ChannelSpec(topic, schema_name, schema_bytes(schema), latched)


def to_ns(t_s: float) -> int:
    """Seconds → integer nanoseconds (MCAP times), never negative."""
    return max(0, round(t_s * 1e9))


def _dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _pose(p: Pose2D, nd: int | None = None) -> Json:
    """A Foxglove pose; ``nd``: round to that many decimals (display-only channels)."""
    x, y, z, w = (0.0, 0.0, 0.0, 1.0) if not math.isfinite(p.yaw) else yaw_to_quat(p.yaw)
    px, py = p.x, p.y
    if nd is not None:
        px, py, z, w = round(px, nd), round(py, nd), round(z, nd), round(w, nd)
    return {"position": {"x": px, "y": py, "z": 0.0},
            "orientation": {"x": x, "y": y, "z": z, "w": w}}


def _floats32(arr: Any) -> str:
    """A float array as a JSON array text: float32's shortest repr, ``null`` if not finite."""
    a = np.asarray(arr, dtype=np.float32)
    text = a.astype(str)
    bad = ~np.isfinite(a)
    if bad.any():
        text[bad] = "null"
    return "[" + ",".join(text.tolist()) + "]"


def _num(nd: int | None) -> Callable[[float], float | None]:
    def conv(v: float) -> float | None:
        if not math.isfinite(v):
            return None
        return v if nd is None else round(v, nd)
    return conv


def _field_converter(hint: Any, nd: int | None) -> Callable[[Any], Any]:
    """A converter for one dataclass field type: the same output as ``to_jsonable``, faster."""
    num = _num(nd)
    args = typing.get_args(hint)
    if hint is float:
        return num
    if hint in (int, str, bool):
        return lambda v: v
    if hint is Pose2D:
        return lambda p: {"x": num(p.x), "y": num(p.y), "yaw": num(p.yaw)}
    if typing.get_origin(hint) is tuple and args and all(a is float for a in args
                                                         if a is not Ellipsis):
        return lambda t: [num(v) for v in t]
    return lambda v: to_jsonable(v, nd)


_CONVERTERS: dict[tuple[type[Any], int | None], Callable[[Any], Json]] = {}


def _converter(cls: type[Any], nd: int | None) -> Callable[[Any], Json]:
    """``to_jsonable`` for one message class, with the per-field work decided once."""
    convert = _CONVERTERS.get((cls, nd))
    if convert is None:
        hints = _hints(cls)
        fields = [(f.name, _field_converter(hints[f.name], nd))
                  for f in dataclasses.fields(cls)]

        def convert(msg: Any) -> Json:
            return {name: conv(getattr(msg, name)) for name, conv in fields}
        _CONVERTERS[(cls, nd)] = convert
    return convert


def primary_channel(topic_name: str) -> str:
    """The recorded channel a bus topic's messages go to (``/tf/map_odom`` → ``/tf``)."""
    return "/tf" if topic_name == MAP_TO_ODOM.name else topic_name


class Codec:
    """Encodes bus messages into channel payloads (JSON bytes).

    Args:
        time_offset_s: added to message stamps for Foxglove timestamps (wall-clock times).
    """

    def __init__(self, time_offset_s: float) -> None:
        self.time_offset_s = time_offset_s
        self._specs: dict[str, ChannelSpec] = {}
        for topic in ALL_TOPICS:
            schema = _FOXGLOVE_BY_TOPIC.get(topic.name, f"curio.{topic.type.__name__}")
            self._specs[topic.name] = _spec(primary_channel(topic.name), schema, topic.latched)
        self._tf = _spec("/tf", "foxglove.FrameTransform", False)
        self._tf_static = _spec("/tf_static", "foxglove.FrameTransform", True)
        self._scene = _spec("/scene", "foxglove.SceneUpdate", True)
        self._log = _spec("/log", "foxglove.Log", False)

    def time(self, stamp: float) -> Json:
        """A Foxglove ``{sec, nsec}`` time for a message stamp."""
        ns = to_ns(stamp + self.time_offset_s)
        return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}

    def spec(self, topic_name: str) -> ChannelSpec:
        """The primary channel of a bus topic."""
        return self._specs[topic_name]

    def encode(self, topic_name: str, msg: Any) -> list[Encoded]:
        """The channel payloads of one bus message (one, or two for ``/odom``)."""
        spec = self._specs[topic_name]
        enc = _ENCODERS.get(topic_name)
        nd = None if topic_name in REPLAY_INPUTS else OUTPUT_DIGITS
        out: list[Encoded] = [(spec, enc(self, msg, nd) if enc
                               else _dumps(_converter(type(msg), nd)(msg)))]
        if isinstance(msg, m.Odometry) and topic_name == "/odom":
            out.append((self._tf, _dumps(self._transform(msg.stamp, msg.pose, msg.frame_id,
                                                         msg.child_frame_id, nd))))
        return out

    def _transform(self, stamp: float, pose: Pose2D, parent: str, child: str,
                   nd: int | None = None) -> Json:
        p = _pose(pose, nd)
        return {"timestamp": self.time(stamp), "parent_frame_id": parent,
                "child_frame_id": child, "translation": p["position"],
                "rotation": p["orientation"]}

    def scan(self, msg: m.LaserScan, nd: int | None = None) -> bytes:
        """``foxglove.LaserScan``, always exact, with the Curio fields under ``curio``."""
        n = len(msg.ranges_m)
        nan = np.flatnonzero(np.isnan(np.asarray(msg.ranges_m))).tolist()
        head = {"timestamp": self.time(msg.stamp), "frame_id": msg.frame_id,
                "pose": _pose(Pose2D()), "start_angle": msg.angle_min_rad,
                "end_angle": msg.angle_min_rad + (n - 1) * msg.angle_increment_rad,
                "curio": {"stamp": msg.stamp, "angle_min_rad": msg.angle_min_rad,
                          "angle_increment_rad": msg.angle_increment_rad,
                          "range_min_m": msg.range_min_m, "range_max_m": msg.range_max_m,
                          "scan_time_s": msg.scan_time_s, "nan": nan,
                          "has_intensities": msg.intensities is not None}}
        text = json.dumps(head, separators=(",", ":"), allow_nan=False)[:-1]
        inten = _floats32(msg.intensities) if msg.intensities is not None else "[]"
        return (f'{text},"ranges":{_floats32(msg.ranges_m)},"intensities":{inten}}}'
                .encode())

    def pose(self, msg: m.PoseWithCovariance, nd: int | None = None) -> bytes:
        """``foxglove.PoseInFrame`` (the stamp and the covariance under ``curio``)."""
        cov = list(msg.covariance) if nd is None else [round(v, nd + 3) for v in msg.covariance]
        return _dumps({"timestamp": self.time(msg.stamp), "frame_id": msg.frame_id,
                       "pose": _pose(msg.pose, nd),
                       "curio": {"stamp": msg.stamp, "covariance": cov}})

    def map_odom(self, msg: m.Transform, nd: int | None = None) -> bytes:
        """``foxglove.FrameTransform`` of the ``map → odom`` correction."""
        return _dumps(self._transform(msg.stamp, msg.transform, msg.frame_id,
                                      msg.child_frame_id, nd))

    def grid(self, msg: m.GridMessage, nd: int | None = None) -> bytes:
        """``foxglove.Grid``: int8 cells, rows from the bottom."""
        data = np.ascontiguousarray(msg.data, dtype=np.int8)
        h, w = data.shape
        field = {"name": "occupancy" if msg.kind == "map" else "cost", "offset": 0, "type": 2}
        return _dumps({
            "timestamp": self.time(msg.stamp), "frame_id": msg.frame_id,
            "pose": _pose(msg.origin), "column_count": w,
            "cell_size": {"x": msg.resolution_m, "y": msg.resolution_m},
            "row_stride": w, "cell_stride": 1, "fields": [field],
            "data": base64.b64encode(data.tobytes()).decode("ascii"),
            "curio": {"stamp": msg.stamp, "version": msg.version, "kind": msg.kind,
                      "resolution_m": msg.resolution_m, "origin": to_jsonable(msg.origin),
                      "rows": h}})

    def path(self, msg: m.Path, nd: int | None = None) -> bytes:
        """``foxglove.PosesInFrame``."""
        return _dumps({"timestamp": self.time(msg.stamp), "frame_id": msg.frame_id,
                       "poses": [_pose(p, nd) for p in msg.poses],
                       "curio": {"stamp": msg.stamp}})

    def obstacles(self, msg: m.Obstacles, nd: int | None = None) -> bytes:
        """``foxglove.SceneUpdate``: segments as a line list, circles as flat cylinders
        (millimetres: drawn, never replayed)."""
        points = [{"x": round(x, 3), "y": round(y, 3), "z": 0.05}
                  for seg in msg.segments for (x, y) in seg]
        lines = [{"type": 2, "pose": _pose(Pose2D()), "thickness": 0.04,
                  "scale_invariant": False, "points": points,
                  "color": {"r": 1.0, "g": 0.4, "b": 0.0, "a": 1.0}}] if points else []
        cyl = [{"pose": _pose(Pose2D(x, y, 0.0), 3),
                "size": {"x": round(2 * r, 3), "y": round(2 * r, 3), "z": 0.1},
                "bottom_scale": 1.0, "top_scale": 1.0,
                "color": {"r": 1.0, "g": 0.4, "b": 0.0, "a": 0.6}} for x, y, r in msg.circles]
        entity = {"timestamp": self.time(msg.stamp), "frame_id": msg.frame_id,
                  "id": "obstacles", "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
                  "lines": lines, "cylinders": cyl}
        return _dumps({"deletions": [], "entities": [entity]})

    def log(self, stamp: float, levelno: int, message: str, name: str, file: str,
            line: int) -> Encoded:
        """One Python log record as ``foxglove.Log`` on ``/log``."""
        level = LOG_LEVELS.get(levelno - levelno % 10, 0)
        return self._log, _dumps({"timestamp": self.time(stamp), "level": level,
                                  "message": message, "name": name, "file": file,
                                  "line": max(0, line)})

    def statics(self, stamp: float, mounts: dict[str, Pose2D],
                footprint: list[tuple[float, float]],
                markers: list[tuple[str, Pose2D]]) -> list[Encoded]:
        """The fixed frames (``/tf_static``) and the scene (``/scene``) at the start.

        Args:
            mounts: child frame → its pose in ``base_link`` (``laser``, ``imu_link``).
            footprint: the footprint polygon in ``base_link``, metres.
            markers: labelled poses in ``map`` (waypoints, tour stops).
        """
        out: list[Encoded] = [(self._tf_static, _dumps(self._transform(stamp, pose,
                                                                      "base_link", child)))
                              for child, pose in mounts.items()]
        ring = [{"x": x, "y": y, "z": 0.02} for x, y in footprint]
        white = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}
        body = {"timestamp": self.time(stamp), "frame_id": "base_link", "id": "footprint",
                "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": True,
                "lines": [{"type": 1, "pose": _pose(Pose2D()), "thickness": 0.03,
                           "scale_invariant": False, "points": ring,
                           "color": {"r": 0.2, "g": 0.6, "b": 1.0, "a": 1.0}}]}
        marks = {"timestamp": self.time(stamp), "frame_id": "map", "id": "waypoints",
                 "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
                 "spheres": [{"pose": _pose(p), "size": {"x": 0.2, "y": 0.2, "z": 0.2},
                              "color": {"r": 0.1, "g": 0.8, "b": 0.3, "a": 0.9}}
                             for _, p in markers],
                 "texts": [{"pose": _pose(Pose2D(p.x, p.y, 0.0)), "billboard": True,
                            "font_size": 14.0, "scale_invariant": True, "color": white,
                            "text": label} for label, p in markers]}
        out.append((self._scene, _dumps({"deletions": [], "entities": [body, marks]})))
        return out


_FOXGLOVE_BY_TOPIC: dict[str, str] = {
    "/scan": "foxglove.LaserScan",
    "/pose": "foxglove.PoseInFrame",
    "/initialpose": "foxglove.PoseInFrame",
    MAP_TO_ODOM.name: "foxglove.FrameTransform",
    "/map": "foxglove.Grid",
    "/costmap": "foxglove.Grid",
    "/local_costmap": "foxglove.Grid",
    "/plan": "foxglove.PosesInFrame",
    "/local_plan": "foxglove.PosesInFrame",
    "/obstacles": "foxglove.SceneUpdate",
}
_ENCODERS: dict[str, Callable[[Codec, Any, int | None], bytes]] = {
    "/scan": Codec.scan,
    "/pose": Codec.pose,
    "/initialpose": Codec.pose,
    MAP_TO_ODOM.name: Codec.map_odom,
    "/map": Codec.grid,
    "/costmap": Codec.grid,
    "/local_costmap": Codec.grid,
    "/plan": Codec.path,
    "/local_plan": Codec.path,
    "/obstacles": Codec.obstacles,
}


# --- decoding (curio replay, the tests) ---------------------------------------------------------
_HINTS: dict[type[Any], dict[str, Any]] = {}


def _hints(cls: type[Any]) -> dict[str, Any]:
    """The type hints of a Curio message class (cached)."""
    hints = _HINTS.get(cls)
    if hints is None:
        hints = _HINTS[cls] = typing.get_type_hints(cls, vars(m))
    return hints


def _value(hint: Any, value: Any) -> Any:
    """One field from its JSON form (the inverse of ``to_jsonable`` for Curio's field types)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Union or (origin is not None and type(None) in args):
        if value is None:
            return None
        return _value(next(a for a in args if a is not type(None)), value)
    if hint is float:
        return math.nan if value is None else float(value)
    if hint in (int, str, bool):
        return hint(value)
    if hint is Pose2D:
        return Pose2D(*(math.nan if value[k] is None else float(value[k])
                        for k in ("x", "y", "yaw")))
    if origin is tuple:
        items = [args[0]] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
        return tuple(_value(h, v) for h, v in zip(items, value, strict=True))
    if origin is Literal or origin is dict or hint is Any:
        return value
    if origin is np.ndarray:
        return np.array([math.nan if v is None else v for v in value], dtype=np.float32)
    if dataclasses.is_dataclass(hint):
        return from_jsonable(hint, value)  # type: ignore[arg-type]
    return value


def from_jsonable(cls: type[Any], data: Json) -> Any:
    """A Curio message (or nested dataclass) from its ``to_jsonable`` form."""
    hints = _hints(cls)
    return cls(**{f.name: _value(hints[f.name], data[f.name])
                  for f in dataclasses.fields(cls) if f.name in data})


def _scan(body: Json) -> m.LaserScan:
    c = body["curio"]
    ranges = np.array([math.inf if v is None else v for v in body["ranges"]], dtype=np.float32)
    if c["nan"]:
        ranges[np.asarray(c["nan"], dtype=np.int64)] = np.nan
    inten = (np.array([math.nan if v is None else v for v in body["intensities"]],
                      dtype=np.float32) if c.get("has_intensities") else None)
    return m.LaserScan(float(c["stamp"]), float(c["angle_min_rad"]),
                       float(c["angle_increment_rad"]), float(c["range_min_m"]),
                       float(c["range_max_m"]), ranges, inten, float(c["scan_time_s"]),
                       str(body["frame_id"]))


def _pose2d(p: Json) -> Pose2D:
    """A Foxglove pose (yaw only) as a Pose2D: positions exact, yaw to about 1e-16 rad."""
    q = p["orientation"]
    return Pose2D(float(p["position"]["x"]), float(p["position"]["y"]),
                  2.0 * math.atan2(q["z"], q["w"]))


def _path(body: Json) -> m.Path:
    poses = tuple(_pose2d(p) for p in body["poses"])
    return m.Path(float(body["curio"]["stamp"]), poses, str(body["frame_id"]))


def _pose_cov(body: Json) -> m.PoseWithCovariance:
    c = body["curio"]
    return m.PoseWithCovariance(float(c["stamp"]), _pose2d(body["pose"]),
                                tuple(float(v) for v in c["covariance"]), str(body["frame_id"]))


_TOPICS: dict[str, Topic[Any]] = {t.name: t for t in ALL_TOPICS}


def decode(channel: str, data: bytes) -> tuple[Topic[Any], Any] | None:
    """The bus topic and message of one recorded payload; None for channels that are not one
    bus topic's (``/tf``, ``/tf_static``, ``/scene``, ``/log``).

    Raises:
        ValueError: the payload is not what the channel carries (a corrupt or foreign file).
    """
    topic = _TOPICS.get(channel)
    if topic is None:
        return None
    try:
        body = json.loads(data)
        if channel == "/scan":
            return topic, _scan(body)
        if channel in ("/plan", "/local_plan"):
            return topic, _path(body)
        if channel in ("/map", "/costmap", "/local_costmap"):
            return topic, _grid(body)
        if channel in ("/pose", "/initialpose"):
            return topic, _pose_cov(body)
        if channel == "/obstacles":
            return None  # drawn, not replayed: no exact form is kept
        return topic, from_jsonable(topic.type, body)
    except (KeyError, TypeError, ValueError, IndexError, StopIteration) as exc:
        raise ValueError(f"{channel}: a message that is not a Curio {topic.type.__name__} "
                         f"({type(exc).__name__}: {exc})") from None


def _grid(body: Json) -> m.GridMessage:
    c = body["curio"]
    raw = np.frombuffer(base64.b64decode(body["data"]), dtype=np.int8)
    data = raw.reshape(int(c["rows"]), int(body["column_count"])).copy()
    return m.GridMessage(float(c["stamp"]), data, float(c["resolution_m"]),
                         _value(Pose2D, c["origin"]), int(c["version"]), str(c["kind"]),
                         str(body["frame_id"]))
