"""Plain JSON data from Curio's values: the one converter for reports, the dashboard and
tree snapshots.

Dataclasses become objects, poses ``{"x", "y", "yaw"}``, tuples and sets lists, numpy values
their Python equivalents; non-finite floats become ``null`` (JSON has no ``inf``); anything else
its ``str``. With ``ndigits`` floats are rounded (reports keep micrometres, snapshots less).
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

import numpy as np

from curio.core.geometry import Pose2D

__all__ = ["to_json", "to_jsonable"]


def to_jsonable(value: Any, ndigits: int | None = None) -> Any:
    """``value`` as JSON data (see the module docstring); floats rounded to ``ndigits``."""
    if isinstance(value, Pose2D):
        return {"x": _num(value.x, ndigits), "y": _num(value.y, ndigits),
                "yaw": _num(value.yaw, ndigits)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name), ndigits)
                for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_jsonable(v, ndigits) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [to_jsonable(v, ndigits) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist(), ndigits)
    if isinstance(value, np.generic):
        return to_jsonable(value.item(), ndigits)
    if isinstance(value, float):
        return _num(value, ndigits)
    if value is None or isinstance(value, str | int | bool):
        return value
    return str(value)


def _num(value: float, ndigits: int | None) -> float | None:
    if not math.isfinite(value):
        return None
    return value if ndigits is None else round(value, ndigits)


def to_json(value: Any) -> str:
    """Compact JSON text of :func:`to_jsonable` ``(value)``."""
    return json.dumps(to_jsonable(value), separators=(",", ":"), allow_nan=False)
