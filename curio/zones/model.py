"""A zone: a named keep-out or speed-limit polygon in ``map`` (metres), validated.

Every error is a :class:`ZoneError` whose message is one sentence naming the value, what is
wrong and what is allowed, for the dashboard and the CLI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from .geometry import polygon_area, self_intersects

__all__ = ["KINDS", "MAX_VERTICES", "Zone", "ZoneError", "ZoneKind", "make_zone"]

ZoneKind = Literal["keepout", "speed"]
KINDS: tuple[str, ...] = ("keepout", "speed")
MAX_VERTICES = 200
MAX_NAME_CHARS = 60
MAX_COORD_M = 10_000.0
MIN_AREA_M2 = 0.01


class ZoneError(ValueError):
    """A zone that cannot be saved; ``str()`` is a sentence for the operator."""


@dataclass(frozen=True)
class Zone:
    """A zone of one map.

    Attributes:
        id: never reused within a map's zone file.
        name: 1–60 characters.
        kind: ``keepout`` (never entered by any part of the rover) or ``speed`` (driven at no
            more than ``speed_limit_mps`` while any part of the rover is in it).
        polygon: vertices ``(x, y)`` in ``map``, metres; a simple polygon, either orientation.
        speed_limit_mps: the limit of a speed zone, m/s (None for keep-out).
    """

    id: int
    name: str
    kind: ZoneKind
    polygon: tuple[tuple[float, float], ...]
    speed_limit_mps: float | None = None

    def vertices(self) -> npt.NDArray[np.float64]:
        """The polygon as an ``(N, 2)`` array (metres, ``map``)."""
        return np.asarray(self.polygon, dtype=np.float64).reshape(-1, 2)

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form (the zone file, the API)."""
        return {"id": self.id, "name": self.name, "kind": self.kind,
                "polygon": [[x, y] for x, y in self.polygon],
                "speed_limit_mps": self.speed_limit_mps}

    @staticmethod
    def from_json(data: Any, max_speed_mps: float) -> Zone:
        """Parse and validate one zone of a file or a request.

        Raises:
            ZoneError: a field is missing or wrong.
        """
        if not isinstance(data, dict):
            raise ZoneError(f"a zone must be an object {{name, kind, polygon, "
                            f"speed_limit_mps?}}, got {data!r}")
        zid = data.get("id", 0)
        if isinstance(zid, bool) or not isinstance(zid, int) or zid < 0:
            raise ZoneError(f"a zone's id must be a whole number >= 0, got {zid!r}")
        return make_zone(zid, data.get("name"), data.get("kind"), data.get("polygon"),
                         data.get("speed_limit_mps"), max_speed_mps)


def _name(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ZoneError(f"a zone needs a name of 1–{MAX_NAME_CHARS} characters, got {value!r}")
    name = value.strip()
    if len(name) > MAX_NAME_CHARS:
        raise ZoneError(f"the zone name {name[:20]!r}… is {len(name)} characters long; "
                        f"at most {MAX_NAME_CHARS} are allowed")
    return name


def _polygon(value: Any) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, (list, tuple)) or not 3 <= len(value) <= MAX_VERTICES:
        count = len(value) if isinstance(value, (list, tuple)) else "no"
        raise ZoneError(f"a zone's polygon needs 3 to {MAX_VERTICES} points [[x, y], ...] in "
                        f"metres, got {count} points")
    out = []
    for i, pt in enumerate(value):
        if (not isinstance(pt, (list, tuple)) or len(pt) != 2 or any(
                isinstance(c, bool) or not isinstance(c, (int, float)) for c in pt)):
            raise ZoneError(f"point {i} of the polygon must be [x, y] in metres, got {pt!r}")
        x, y = float(pt[0]), float(pt[1])
        if not (math.isfinite(x) and math.isfinite(y)) or max(abs(x), abs(y)) > MAX_COORD_M:
            raise ZoneError(f"point {i} of the polygon must be finite and within "
                            f"±{MAX_COORD_M:g} m, got {pt!r}")
        out.append((round(x, 4), round(y, 4)))
    arr = np.asarray(out, dtype=np.float64)
    if self_intersects(arr):
        raise ZoneError("the polygon's edges cross each other; draw its outline without "
                        "crossings (a simple polygon)")
    area = abs(polygon_area(arr))
    if area < MIN_AREA_M2:
        raise ZoneError(f"the polygon encloses {area:.4f} m²; a zone needs at least "
                        f"{MIN_AREA_M2} m² (are the points in a line?)")
    return tuple(out)


def make_zone(zid: int, name: Any, kind: Any, polygon: Any, speed_limit_mps: Any,
              max_speed_mps: float) -> Zone:
    """A validated zone.

    Args:
        zid: its id.
        name, kind, polygon, speed_limit_mps: as sent (checked here).
        max_speed_mps: the fastest the rover drives; a speed limit must be below it.

    Raises:
        ZoneError: naming the value, what is wrong and what is allowed.
    """
    if kind not in KINDS:
        raise ZoneError(f"a zone's kind must be 'keepout' or 'speed', got {kind!r}")
    limit: float | None = None
    if kind == "speed":
        if isinstance(speed_limit_mps, bool) or not isinstance(speed_limit_mps, (int, float)) \
                or not 0.0 < float(speed_limit_mps) <= max_speed_mps:
            raise ZoneError(f"a speed zone needs speed_limit_mps between 0 and "
                            f"{max_speed_mps:g} m/s (the rover's top speed), got "
                            f"{speed_limit_mps!r}")
        limit = round(float(speed_limit_mps), 4)
    elif speed_limit_mps is not None:
        raise ZoneError("a keep-out zone has no speed limit (the rover never enters it); "
                        "leave speed_limit_mps out or make it a 'speed' zone")
    return Zone(zid, _name(name), kind, _polygon(polygon), limit)
