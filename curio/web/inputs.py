"""What the dashboard accepts from a browser, and how it says no.

The validation here is shared by the REST API (:mod:`curio.web.api`) and the WebSocket
(:mod:`curio.web.session`), so a command, a pose or a path number is judged the same way on
both. A refusal is a :class:`CommandError` whose message tells the operator what was wrong and
what is allowed: the WebSocket answers it with ``{"t": "error", ...}``, the REST API with
``400`` and the JSON body of :func:`http_error`.

JSON is parsed strictly: ``NaN``/``Infinity`` and integers longer than
:data:`MAX_INT_DIGITS` digits (``10**400`` would overflow a float) are refused with a sentence,
never a 500. Goals, waypoints and initial poses outside the map are refused with the map's
bounds (:class:`MapBounds`).

Poses are in ``map`` (metres, radians); velocities in m/s and rad/s.
"""

from __future__ import annotations

import json
import math
import re
import uuid
from dataclasses import dataclass
from typing import Any, get_args

from aiohttp import web

from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorAction, OperatorCommand

__all__ = [
    "ACTIONS",
    "MAX_INT_DIGITS",
    "REQUEST_ID",
    "CommandError",
    "MapBounds",
    "build_command",
    "describe_path_ids",
    "http_error",
    "parse_json_object",
    "parse_path_number",
    "parse_pose",
    "parse_teleop",
    "parse_tour_id",
]

ACTIONS: tuple[str, ...] = get_args(OperatorAction)
REQUEST_ID = re.compile(r"^[A-Za-z0-9_.:-]{1,64}$")
# Longer integers in a JSON message are refused (no coordinate or count needs more).
MAX_INT_DIGITS = 15


class CommandError(ValueError):
    """An operator command or input that cannot be accepted; the message says why."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


def http_error(cls: type[web.HTTPException], message: str,
               headers: dict[str, str] | None = None) -> web.HTTPException:
    """An aiohttp HTTP error whose body is ``{"error": message, "status": code}``."""
    body = json.dumps({"error": message, "status": cls.status_code}, ensure_ascii=False)
    exc = cls.__new__(cls)
    # Bypass subclasses' own __init__ (some need extra arguments); the base sets the status.
    web.HTTPException.__init__(exc, text=body, content_type="application/json",
                               headers=headers)
    return exc


class _NumberError(ValueError):
    """A number JSON may carry but the dashboard refuses (too long, NaN, Infinity)."""


def _parse_int(text: str) -> int:
    digits = text.lstrip("-")
    if len(digits) > MAX_INT_DIGITS:
        raise _NumberError(f"the number {text[:12]}… ({len(digits)} digits) is too large; "
                           f"numbers have at most {MAX_INT_DIGITS} digits")
    return int(text)


def _parse_constant(name: str) -> float:
    raise _NumberError(f"{name} is not a number the rover accepts; send a finite number")


def parse_json_object(text: str | bytes) -> dict[str, Any]:
    """Parse a JSON object or raise :class:`CommandError` saying what is wrong."""
    try:
        value = json.loads(text, parse_int=_parse_int, parse_constant=_parse_constant)
    except _NumberError as exc:
        raise CommandError(str(exc)) from None
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise CommandError(f"message is not valid JSON: {exc}") from None
    if not isinstance(value, dict):
        raise CommandError(f"message must be a JSON object, got {type(value).__name__}")
    return value


def describe_path_ids(ids: list[int]) -> str:
    """``[0, 1, 2, 3, 4]`` → ``"0–4"``; a non-contiguous list is comma-separated."""
    if not ids:
        return "none (create one first)"
    ids = sorted(ids)
    if len(ids) > 2 and ids == list(range(ids[0], ids[-1] + 1)):
        return f"{ids[0]}–{ids[-1]}"
    return ", ".join(str(i) for i in ids)


def _number(body: dict[str, Any], key: str, *, required: bool = True) -> float | None:
    value = body.get(key)
    if value is None:
        if required:
            raise CommandError(f"'{key}' is required (a number)")
        return None
    if not _finite_number(value):
        raise CommandError(f"'{key}' must be a finite number, got {_short(value)}")
    return float(value)


def _finite_number(value: Any) -> bool:
    """A JSON number that is finite as a float (huge integers are not)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    if isinstance(value, int):
        return bool(abs(value) < 10**MAX_INT_DIGITS)
    return math.isfinite(value)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "…"


@dataclass(frozen=True, slots=True)
class MapBounds:
    """The map's rectangle: its lower-left ``origin`` in map (m, m, rad) and its size (m)."""

    origin: Pose2D
    width_m: float
    height_m: float

    def contains(self, x_m: float, y_m: float) -> bool:
        """Whether the point (map, metres) lies on the map."""
        u, v = self.origin.inverse().transform_point(x_m, y_m)
        return 0.0 <= u <= self.width_m and 0.0 <= v <= self.height_m

    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in map of the map's corners, metres."""
        corners = [self.origin.transform_point(u, v)
                   for u in (0.0, self.width_m) for v in (0.0, self.height_m)]
        xs, ys = [c[0] for c in corners], [c[1] for c in corners]
        return min(xs), max(xs), min(ys), max(ys)

    def describe(self) -> str:
        """``x from -5.00 to 25.00 m, y from -3.00 to 17.00 m``."""
        x0, x1, y0, y1 = self.extent()
        return f"x from {x0:.2f} to {x1:.2f} m, y from {y0:.2f} to {y1:.2f} m"

    def require(self, x_m: float, y_m: float, what: str) -> None:
        """Raise :class:`CommandError` naming the bounds when the point is off the map."""
        if not self.contains(x_m, y_m):
            raise CommandError(f"{what} ({x_m:.2f}, {y_m:.2f}) is outside the map; the map "
                               f"covers {self.describe()}")


def parse_pose(body: dict[str, Any]) -> Pose2D:
    """``{x_m, y_m, yaw_rad?}`` → a pose in map (yaw defaults to 0)."""
    x = _number(body, "x_m")
    y = _number(body, "y_m")
    yaw = _number(body, "yaw_rad", required=False)
    assert x is not None and y is not None
    return Pose2D(x, y, 0.0 if yaw is None else math.remainder(yaw, 2 * math.pi))


def parse_teleop(body: dict[str, Any]) -> tuple[float, float, int | None]:
    """``{linear_mps?, angular_radps?, seq?}`` → (m/s, rad/s, sequence number or None).

    A missing velocity is 0; ``seq`` orders a client's teleop messages.
    """
    lin, ang = body.get("linear_mps", 0.0), body.get("angular_radps", 0.0)
    for key, value in (("linear_mps", lin), ("angular_radps", ang)):
        if not _finite_number(value):
            raise CommandError(f"teleop '{key}' must be a finite number, got {_short(value)}")
    seq = body.get("seq")
    if seq is not None and (not isinstance(seq, int) or isinstance(seq, bool)):
        raise CommandError(f"teleop 'seq' must be an integer, got {seq!r}")
    return float(lin), float(ang), seq


def parse_path_number(value: Any, paths: Any) -> int:
    """Validate a path number typed by the operator against the path manager's paths."""
    if isinstance(value, bool):
        raise CommandError(f"path number must be a whole number like 2, got {value!r}")
    if isinstance(value, str):
        text = value.strip()
        if not text:
            raise CommandError("type a path number first (e.g. 1), then press Enter")
        if not re.fullmatch(r"[+-]?\d+", text):
            raise CommandError(f"path number must be a whole number like 2, got '{text}'")
        number = int(text)
    elif isinstance(value, int):
        number = value
    elif isinstance(value, float) and value.is_integer():
        number = int(value)
    else:
        raise CommandError(f"path number must be a whole number like 2, got {value!r}")
    if paths is not None:
        ids = [int(p.id) for p in paths.list_paths()]
        if number not in ids:
            raise CommandError(f"There is no path {number}; paths are {describe_path_ids(ids)}")
    elif number < 0:
        raise CommandError(f"There is no path {number}; path numbers start at 0")
    return number


def build_command(body: dict[str, Any], clock: Clock, paths: Any,
                  source: str = "web", bounds: MapBounds | None = None) -> OperatorCommand:
    """Turn ``{action, path_id?, goal?, tour_id?, request_id?}`` into an
    :class:`OperatorCommand` (``tour_id`` with ``start_tour``: which tour; none = the first).

    Args:
        body: the command as sent (``goal`` in map, metres and radians).
        clock: stamps the command.
        paths: the path manager that ``path_id`` is checked against, or None.
        source: who sent it (``web:<operator>``).
        bounds: the map; a goal off it is refused (None: not checked).

    Raises:
        CommandError: the action is unknown, a field is missing or invalid (message says which).
    """
    action = body.get("action")
    if action not in ACTIONS:
        raise CommandError(f"unknown action {action!r}; allowed: {', '.join(ACTIONS)}")
    request_id = body.get("request_id") or uuid.uuid4().hex
    if not isinstance(request_id, str) or not REQUEST_ID.match(request_id):
        raise CommandError("request_id must be 1–64 characters of letters, digits, _ . : -")
    path_id: int | None = None
    goal: Pose2D | None = None
    tour_id: int | None = None
    if action == "start_tour" and body.get("tour_id") is not None:
        tour_id = parse_tour_id(body["tour_id"])
    if action == "select_path":
        if "path_id" not in body:
            raise CommandError("select_path needs 'path_id' (the path number)")
        path_id = parse_path_number(body["path_id"], paths)
    elif action == "goto":
        raw = body.get("goal")
        if not isinstance(raw, dict):
            raise CommandError("goto needs 'goal': {x_m, y_m, yaw_rad?} in map")
        goal = parse_pose(raw)
        if bounds is not None:
            bounds.require(goal.x, goal.y, "the goal")
    return OperatorCommand(clock.now(), action, path_id=path_id, goal=goal, source=source,
                           request_id=request_id, tour_id=tour_id)


def parse_tour_id(value: Any) -> int:
    """A tour number (1 or more) as sent in a command or a URL."""
    if isinstance(value, str) and re.fullmatch(r"\s*\d{1,9}\s*", value):
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise CommandError(f"a tour number must be a whole number of 1 or more, got "
                           f"{_short(value)}")
    return value
