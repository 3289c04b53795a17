"""What the dashboard accepts from a browser, and how it says no.

The validation here is shared by the REST API (:mod:`curio.web.api`) and the WebSocket
(:mod:`curio.web.session`), so a command, a pose or a path number is judged the same way on
both. A refusal is a :class:`CommandError` whose message tells the operator what was wrong and
what is allowed: the WebSocket answers it with ``{"t": "error", ...}``, the REST API with
``400`` and the JSON body of :func:`http_error`.

Poses are in ``map`` (metres, radians); velocities in m/s and rad/s.
"""

from __future__ import annotations

import json
import math
import re
import uuid
from typing import Any, get_args

from aiohttp import web

from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorAction, OperatorCommand

__all__ = [
    "ACTIONS",
    "CommandError",
    "build_command",
    "describe_path_ids",
    "http_error",
    "parse_json_object",
    "parse_path_number",
    "parse_pose",
    "parse_teleop",
]

ACTIONS: tuple[str, ...] = get_args(OperatorAction)
_REQUEST_ID = re.compile(r"^[A-Za-z0-9_.:-]{1,64}$")


class CommandError(ValueError):
    """An operator command or input that cannot be accepted; the message says why."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


def http_error(cls: type[web.HTTPException], message: str) -> web.HTTPException:
    """An aiohttp HTTP error whose body is ``{"error": message, "status": code}``."""
    body = json.dumps({"error": message, "status": cls.status_code}, ensure_ascii=False)
    exc = cls.__new__(cls)
    # Bypass subclasses' own __init__ (some need extra arguments); the base sets the status.
    web.HTTPException.__init__(exc, text=body, content_type="application/json")
    return exc


def parse_json_object(text: str | bytes) -> dict[str, Any]:
    """Parse a JSON object or raise :class:`CommandError` saying what is wrong."""
    try:
        value = json.loads(text)
    except (ValueError, UnicodeDecodeError) as exc:
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
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CommandError(f"'{key}' must be a finite number, got {value!r}")
    return float(value)


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
        if (isinstance(value, bool) or not isinstance(value, int | float)
                or not math.isfinite(value)):
            raise CommandError(f"teleop '{key}' must be a finite number, got {value!r}")
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
                  source: str = "web") -> OperatorCommand:
    """Turn ``{action, path_id?, goal?, request_id?}`` into an :class:`OperatorCommand`.

    Args:
        body: the command as sent (``goal`` in map, metres and radians).
        clock: stamps the command.
        paths: the path manager that ``path_id`` is checked against, or None.
        source: who sent it (``web``).

    Raises:
        CommandError: the action is unknown, a field is missing or invalid (message says which).
    """
    action = body.get("action")
    if action not in ACTIONS:
        raise CommandError(f"unknown action {action!r}; allowed: {', '.join(ACTIONS)}")
    request_id = body.get("request_id") or uuid.uuid4().hex
    if not isinstance(request_id, str) or not _REQUEST_ID.match(request_id):
        raise CommandError("request_id must be 1–64 characters of letters, digits, _ . : -")
    path_id: int | None = None
    goal: Pose2D | None = None
    if action == "select_path":
        if "path_id" not in body:
            raise CommandError("select_path needs 'path_id' (the path number)")
        path_id = parse_path_number(body["path_id"], paths)
    elif action == "goto":
        raw = body.get("goal")
        if not isinstance(raw, dict):
            raise CommandError("goto needs 'goal': {x_m, y_m, yaw_rad?} in map")
        goal = parse_pose(raw)
    return OperatorCommand(clock.now(), action, path_id=path_id, goal=goal, source=source,
                           request_id=request_id)
