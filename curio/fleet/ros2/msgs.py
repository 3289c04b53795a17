"""The ROS 2 messages Curio publishes: their definitions, RIHS01 type hashes and CDR encoding.

:data:`DEFINITIONS` lists, for every message type involved (the four published ones and the
types they contain), its fields in order as ``(name, type)`` in ``.msg`` spelling (``float32``,
``float64[36]``, ``int8[]``, ``std_msgs/msg/Header``, ``geometry_msgs/msg/TransformStamped[]``).
From that one table:

* :func:`type_hash` computes the RIHS01 hash of REP-2016 — SHA-256 of the type description
  (the type and every type it refers to, sorted by name; each field's type id, capacity,
  string capacity and nested type name; no default values) as JSON with ``", "`` and
  ``": "`` separators — which ``rmw_zenoh`` puts in every key expression (a subscriber with a
  different hash does not match);
* :func:`serialize` writes a message as CDR (XCDR1, little endian, with the 4-byte
  encapsulation header ``00 01 00 00``), aligning every primitive to its size from the start of
  the payload, strings as a length (with the NUL) and bytes, sequences as a count and elements.

The tests check the definitions against ``rosbags``' own, the hashes against values published
by ROS 2's generated code, and every encoding by decoding it with ``rosbags``.
"""

from __future__ import annotations

import hashlib
import json
import re
import struct
from functools import cache
from typing import Any

import numpy as np

__all__ = ["DEFINITIONS", "dds_type_name", "serialize", "type_hash"]

DEFINITIONS: dict[str, list[tuple[str, str]]] = {
    "builtin_interfaces/msg/Time": [("sec", "int32"), ("nanosec", "uint32")],
    "std_msgs/msg/Header": [("stamp", "builtin_interfaces/msg/Time"), ("frame_id", "string")],
    "std_msgs/msg/String": [("data", "string")],
    "geometry_msgs/msg/Point": [("x", "float64"), ("y", "float64"), ("z", "float64")],
    "geometry_msgs/msg/Quaternion": [("x", "float64"), ("y", "float64"), ("z", "float64"),
                                     ("w", "float64")],
    "geometry_msgs/msg/Vector3": [("x", "float64"), ("y", "float64"), ("z", "float64")],
    "geometry_msgs/msg/Pose": [("position", "geometry_msgs/msg/Point"),
                               ("orientation", "geometry_msgs/msg/Quaternion")],
    "geometry_msgs/msg/PoseWithCovariance": [("pose", "geometry_msgs/msg/Pose"),
                                             ("covariance", "float64[36]")],
    "geometry_msgs/msg/Twist": [("linear", "geometry_msgs/msg/Vector3"),
                                ("angular", "geometry_msgs/msg/Vector3")],
    "geometry_msgs/msg/TwistWithCovariance": [("twist", "geometry_msgs/msg/Twist"),
                                              ("covariance", "float64[36]")],
    "geometry_msgs/msg/Transform": [("translation", "geometry_msgs/msg/Vector3"),
                                    ("rotation", "geometry_msgs/msg/Quaternion")],
    "geometry_msgs/msg/TransformStamped": [("header", "std_msgs/msg/Header"),
                                           ("child_frame_id", "string"),
                                           ("transform", "geometry_msgs/msg/Transform")],
    "tf2_msgs/msg/TFMessage": [("transforms", "geometry_msgs/msg/TransformStamped[]")],
    "nav_msgs/msg/Odometry": [("header", "std_msgs/msg/Header"), ("child_frame_id", "string"),
                              ("pose", "geometry_msgs/msg/PoseWithCovariance"),
                              ("twist", "geometry_msgs/msg/TwistWithCovariance")],
    "nav_msgs/msg/MapMetaData": [("map_load_time", "builtin_interfaces/msg/Time"),
                                 ("resolution", "float32"), ("width", "uint32"),
                                 ("height", "uint32"), ("origin", "geometry_msgs/msg/Pose")],
    "nav_msgs/msg/OccupancyGrid": [("header", "std_msgs/msg/Header"),
                                   ("info", "nav_msgs/msg/MapMetaData"), ("data", "int8[]")],
    "sensor_msgs/msg/LaserScan": [
        ("header", "std_msgs/msg/Header"), ("angle_min", "float32"), ("angle_max", "float32"),
        ("angle_increment", "float32"), ("time_increment", "float32"), ("scan_time", "float32"),
        ("range_min", "float32"), ("range_max", "float32"), ("ranges", "float32[]"),
        ("intensities", "float32[]")],
}

# type_description_interfaces/msg/FieldType ids of the basic types.
_TYPE_IDS = {"int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
             "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "char": 13, "bool": 15,
             "byte": 16, "string": 17}
_NESTED_ID = 1
_ARRAY, _BOUNDED, _UNBOUNDED = 48, 96, 144
_PRIMS = {"int8": "b", "uint8": "B", "byte": "B", "char": "B", "bool": "?", "int16": "h",
          "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
          "float32": "f", "float64": "d"}
_FIELD = re.compile(r"^(?P<base>[A-Za-z0-9_/]+)(?:\[(?P<size><=)?(?P<n>\d*)\])?$")
ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"


def _parse(spec: str) -> tuple[str, str, int]:
    """``(base type, "single"|"array"|"bounded"|"sequence", size)`` of a field spelling."""
    m = _FIELD.match(spec)
    if m is None:
        raise ValueError(f"bad field type {spec!r}")
    base = m["base"]
    if "[" not in spec:
        return base, "single", 0
    if m["size"]:
        return base, "bounded", int(m["n"])
    if m["n"]:
        return base, "array", int(m["n"])
    return base, "sequence", 0


def dds_type_name(type_name: str) -> str:
    """``pkg/msg/Type`` → ``pkg::msg::dds_::Type_`` (the name ``rmw_zenoh`` keys use)."""
    pkg, kind, name = type_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def _field_type(spec: str) -> dict[str, Any]:
    base, shape, size = _parse(spec)
    nested = base not in _TYPE_IDS
    type_id = _NESTED_ID if nested else _TYPE_IDS[base]
    type_id += {"single": 0, "array": _ARRAY, "bounded": _BOUNDED, "sequence": _UNBOUNDED}[shape]
    return {"type_id": type_id, "capacity": size if shape in ("array", "bounded") else 0,
            "string_capacity": 0, "nested_type_name": base if nested else ""}


def _referenced(type_name: str) -> list[str]:
    seen: set[str] = set()
    todo = [type_name]
    while todo:
        for _, spec in DEFINITIONS[todo.pop()]:
            base = _parse(spec)[0]
            if base not in _TYPE_IDS and base not in seen:
                seen.add(base)
                todo.append(base)
    return sorted(seen)


def _individual(type_name: str) -> dict[str, Any]:
    return {"type_name": type_name,
            "fields": [{"name": n, "type": _field_type(t)} for n, t in DEFINITIONS[type_name]]}


@cache
def type_hash(type_name: str) -> str:
    """The RIHS01 hash of ``type_name`` (``RIHS01_<64 hex>``; see the module docstring)."""
    description = {"type_description": _individual(type_name),
                   "referenced_type_descriptions": [_individual(t)
                                                    for t in _referenced(type_name)]}
    text = json.dumps(description, ensure_ascii=True, separators=(", ", ": "))
    return "RIHS01_" + hashlib.sha256(text.encode("utf-8")).hexdigest()


class _Writer:
    """Appends CDR primitives with the alignment rule (relative to after the header)."""

    def __init__(self) -> None:
        self.buf = bytearray(ENCAPSULATION_CDR_LE)

    def align(self, size: int) -> None:
        self.buf.extend(b"\0" * ((-(len(self.buf) - 4)) % size))

    def prim(self, kind: str, value: Any) -> None:
        fmt = _PRIMS[kind]
        size = struct.calcsize(fmt)
        self.align(size)
        self.buf.extend(struct.pack("<" + fmt, value))

    def string(self, value: str) -> None:
        data = value.encode("utf-8") + b"\0"
        self.prim("uint32", len(data))
        self.buf.extend(data)

    def prims(self, kind: str, values: Any) -> None:
        arr = np.asarray(values, dtype="<" + _PRIMS[kind] if kind != "bool" else "?")
        if arr.size:
            self.align(arr.dtype.itemsize)
            self.buf.extend(arr.tobytes())


def _write(w: _Writer, type_name: str, value: dict[str, Any]) -> None:
    for name, spec in DEFINITIONS[type_name]:
        base, shape, size = _parse(spec)
        v = value[name]
        if shape != "single":
            n = len(v)
            if shape == "array" and n != size:
                raise ValueError(f"{type_name}.{name} needs {size} values, got {n}")
            if shape != "array":
                w.prim("uint32", n)
            if base in _PRIMS:
                w.prims(base, v)
            else:
                for item in v:
                    w.string(item) if base == "string" else _write(w, base, item)
        elif base == "string":
            w.string(v)
        elif base in _PRIMS:
            w.prim(base, v)
        else:
            _write(w, base, v)


def serialize(type_name: str, value: dict[str, Any]) -> bytes:
    """``value`` (nested dicts by field name; arrays as lists or numpy arrays) as CDR bytes."""
    w = _Writer()
    _write(w, type_name, value)
    return bytes(w.buf)
