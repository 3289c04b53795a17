"""JSON Schemas of the recorded channels.

Foxglove and Lichtblick draw a JSON channel natively when its schema is named after one of
Foxglove's well-known message types; the field names and meanings below follow Foxglove's
published message reference (REP-103 angles: counter-clockwise about +z, 0 along +x;
quaternions x, y, z, w; times as ``{sec, nsec}``). Curio adds one optional field, ``curio``,
holding what the Foxglove type cannot carry exactly (the message's own stamp, a scan's range
limits, ...) so a replay rebuilds the very message that was published.

Every other channel carries a Curio message as JSON (``curio.core.jsonable``): its schema is
generated here from the message dataclass (``curio.<ClassName>``).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import types
import typing
from typing import Any, Literal, Union

import numpy as np

from curio.core import messages as msgs
from curio.core.geometry import Pose2D

__all__ = ["FOXGLOVE_SCHEMAS", "curio_schema", "schema_bytes"]

Json = dict[str, Any]

NUM: Json = {"type": "number"}
INT: Json = {"type": "integer"}
STR: Json = {"type": "string"}
BOOL: Json = {"type": "boolean"}


def _obj(title: str, props: Json, description: str = "", required: list[str] | None = None,
         ) -> Json:
    out: Json = {"title": title, "type": "object", "properties": props}
    if description:
        out["description"] = description
    if required:
        out["required"] = required
    return out


def _arr(items: Json) -> Json:
    return {"type": "array", "items": items}


TIME: Json = _obj("time", {"sec": {"type": "integer", "minimum": 0},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}})
DURATION: Json = _obj("duration", {"sec": INT, "nsec": {"type": "integer", "minimum": 0}})
VECTOR2: Json = _obj("foxglove.Vector2", {"x": NUM, "y": NUM})
VECTOR3: Json = _obj("foxglove.Vector3", {"x": NUM, "y": NUM, "z": NUM})
QUATERNION: Json = _obj("foxglove.Quaternion", {"x": NUM, "y": NUM, "z": NUM, "w": NUM})
POSE: Json = _obj("foxglove.Pose", {"position": VECTOR3, "orientation": QUATERNION})
COLOR: Json = _obj("foxglove.Color", {"r": NUM, "g": NUM, "b": NUM, "a": NUM},
                   "RGBA, each 0..1")
POINT3: Json = _obj("foxglove.Point3", {"x": NUM, "y": NUM, "z": NUM})
CURIO_EXTRA: Json = {"type": "object", "description": "Curio: what the Foxglove type cannot "
                     "carry exactly (the message's own fields), for replay"}

LASER_SCAN = _obj("foxglove.LaserScan", {
    "timestamp": TIME, "frame_id": STR, "pose": POSE,
    "start_angle": NUM, "end_angle": NUM,
    "ranges": _arr({"type": ["number", "null"]}), "intensities": _arr(NUM), "curio": CURIO_EXTRA,
}, "One lidar revolution; ranges at equal angles from start_angle to end_angle (rad, "
   "counter-clockwise from +x); null = no return", ["timestamp", "frame_id", "ranges"])
POSE_IN_FRAME = _obj("foxglove.PoseInFrame", {
    "timestamp": TIME, "frame_id": STR, "pose": POSE, "curio": CURIO_EXTRA,
}, "A timestamped pose in a named frame", ["timestamp", "frame_id", "pose"])
POSES_IN_FRAME = _obj("foxglove.PosesInFrame", {
    "timestamp": TIME, "frame_id": STR, "poses": _arr(POSE), "curio": CURIO_EXTRA,
}, "An array of timestamped poses in a named frame (a plan)", ["timestamp", "frame_id", "poses"])
FRAME_TRANSFORM = _obj("foxglove.FrameTransform", {
    "timestamp": TIME, "parent_frame_id": STR, "child_frame_id": STR,
    "translation": VECTOR3, "rotation": QUATERNION, "curio": CURIO_EXTRA,
}, "The pose of child_frame_id in parent_frame_id", ["parent_frame_id", "child_frame_id"])
_FIELD = _obj("foxglove.PackedElementField", {
    "name": STR, "offset": {"type": "integer", "minimum": 0},
    "type": {"type": "integer", "description": "1 UINT8, 2 INT8, 3 UINT16, 4 INT16, 5 UINT32, "
             "6 INT32, 7 FLOAT32, 8 FLOAT64"},
})
GRID = _obj("foxglove.Grid", {
    "timestamp": TIME, "frame_id": STR, "pose": POSE,
    "column_count": {"type": "integer", "minimum": 0}, "cell_size": VECTOR2,
    "row_stride": {"type": "integer", "minimum": 0}, "cell_stride": {"type": "integer",
                                                                     "minimum": 0},
    "fields": _arr(_FIELD),
    "data": {"type": "string", "contentEncoding": "base64", "description": "rows from the "
             "bottom (the pose's corner) up, cells left to right"},
    "curio": CURIO_EXTRA,
}, "A 2D grid: occupancy (-1 unknown, 0..100) or costs (0..100)")
_PRIM_COMMON = {"pose": POSE, "color": COLOR}
LINE_PRIMITIVE = _obj("foxglove.LinePrimitive", {
    **_PRIM_COMMON, "type": {"type": "integer", "description": "0 strip, 1 loop, 2 list"},
    "thickness": NUM, "scale_invariant": BOOL, "points": _arr(POINT3),
    "colors": _arr(COLOR), "indices": _arr(INT)})
CYLINDER_PRIMITIVE = _obj("foxglove.CylinderPrimitive", {
    **_PRIM_COMMON, "size": VECTOR3, "bottom_scale": NUM, "top_scale": NUM})
SPHERE_PRIMITIVE = _obj("foxglove.SpherePrimitive", {**_PRIM_COMMON, "size": VECTOR3})
TEXT_PRIMITIVE = _obj("foxglove.TextPrimitive", {
    "pose": POSE, "billboard": BOOL, "font_size": NUM, "scale_invariant": BOOL,
    "color": COLOR, "text": STR})
SCENE_ENTITY = _obj("foxglove.SceneEntity", {
    "timestamp": TIME, "frame_id": STR, "id": STR, "lifetime": DURATION, "frame_locked": BOOL,
    "metadata": _arr(_obj("foxglove.KeyValuePair", {"key": STR, "value": STR})),
    "lines": _arr(LINE_PRIMITIVE), "cylinders": _arr(CYLINDER_PRIMITIVE),
    "spheres": _arr(SPHERE_PRIMITIVE), "texts": _arr(TEXT_PRIMITIVE),
})
SCENE_UPDATE = _obj("foxglove.SceneUpdate", {
    "deletions": _arr(_obj("foxglove.SceneEntityDeletion", {
        "timestamp": TIME, "type": {"type": "integer", "description": "0 matching id, 1 all"},
        "id": STR})),
    "entities": _arr(SCENE_ENTITY),
}, "Markers: the footprint, waypoints and tour stops, obstacles")
LOG = _obj("foxglove.Log", {
    "timestamp": TIME,
    "level": {"type": "integer", "description": "0 unknown, 1 debug, 2 info, 3 warning, "
              "4 error, 5 fatal"},
    "message": STR, "name": STR, "file": STR, "line": {"type": "integer", "minimum": 0},
}, "A log message")

FOXGLOVE_SCHEMAS: dict[str, Json] = {s["title"]: s for s in (
    LASER_SCAN, POSE_IN_FRAME, POSES_IN_FRAME, FRAME_TRANSFORM, GRID, SCENE_UPDATE, LOG)}


def _type_schema(hint: Any) -> Json:
    """The JSON Schema of one dataclass field type (as ``curio.core.jsonable`` writes it)."""
    if hint is float:
        return {"type": ["number", "null"]}  # null: a non-finite value
    if hint is int:
        return INT
    if hint is bool:
        return BOOL
    if hint is str:
        return STR
    if hint is Pose2D:
        return _obj("curio.Pose2D", {"x": NUM, "y": NUM, "yaw": NUM}, "metres, metres, rad")
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is Literal:
        return {"type": "string", "enum": list(args)}
    if origin in (Union, types.UnionType):
        options = [_type_schema(a) for a in args if a is not type(None)]
        base = options[0] if len(options) == 1 else {"anyOf": options}
        return {"anyOf": [base, {"type": "null"}]} if type(None) in args else base
    if origin is tuple:
        items = args[:1] if len(args) == 2 and args[1] is Ellipsis else args
        if len(set(items)) == 1:
            return _arr(_type_schema(items[0]))
        return {"type": "array", "prefixItems": [_type_schema(a) for a in items]}
    if origin is dict:
        return {"type": "object"}
    if origin is np.ndarray or hint is np.ndarray:
        return _arr({"type": ["number", "null"]})
    return {}


@functools.cache
def curio_schema(cls: type[Any]) -> Json:
    """The JSON Schema ``curio.<ClassName>`` of a Curio message dataclass."""
    hints = typing.get_type_hints(cls, vars(msgs))
    props = {f.name: _type_schema(hints[f.name]) for f in dataclasses.fields(cls)}
    doc = (cls.__doc__ or "").strip().split("\n\n")[0]
    return _obj(f"curio.{cls.__name__}", props, " ".join(doc.split()),
                [f.name for f in dataclasses.fields(cls)
                 if f.default is dataclasses.MISSING
                 and f.default_factory is dataclasses.MISSING])


def schema_bytes(schema: Json) -> bytes:
    """A schema as the compact UTF-8 JSON an MCAP schema record holds."""
    return json.dumps(schema, separators=(",", ":")).encode("utf-8")
