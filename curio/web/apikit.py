"""Small helpers shared by the dashboard's REST modules (tours, the event log, recordings).

Each REST module (:mod:`curio.web.api`, :mod:`curio.web.tours_api`, :mod:`curio.web.log_api`,
:mod:`curio.web.records_api`) is a set of thin module-level handlers and a ``ROUTES`` list;
what they all need to read a request lives here: the JSON body, whole numbers from the URL or
the body, and the building's local time (the tours' time zone, ``tours.timezone``) for
dates typed by people.
"""

from __future__ import annotations

import datetime as dt
from typing import Any, TypeVar
from zoneinfo import ZoneInfo

from aiohttp import web

from curio.core.jsonable import to_json
from curio.web.inputs import http_error, parse_json_object
from curio.web.services import SERVICES

__all__ = ["building_zone", "json_ok", "local_time", "optional_int", "present", "read_body",
           "whole_number"]

T = TypeVar("T")


async def read_body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object ({} when the body is empty; 400 when it is not an object)."""
    raw = await request.read()
    return parse_json_object(raw) if raw else {}


def whole_number(value: Any, what: str, low: int | None = None, text: bool = True) -> int:
    """``value`` (a JSON integer, or with ``text`` the text of one: a URL's) as an int, or
    400 naming ``what``."""
    if text and isinstance(value, str) and value.strip().lstrip("-").isdigit() \
            and len(value) < 16:
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or abs(value) >= 10**15:
        raise http_error(web.HTTPBadRequest, f"{what} must be a whole number, got "
                                             f"{str(value)[:20]!r}")
    if low is not None and value < low:
        raise http_error(web.HTTPBadRequest, f"{what} must be {low} or more, got {value}")
    return value


def optional_int(value: Any, what: str, text: bool = False) -> int | None:
    """Like :func:`whole_number` (text only with ``text``), with None (absent) allowed."""
    return None if value is None or value == "" else whole_number(value, what, text=text)


def building_zone(request: web.Request) -> ZoneInfo:
    """The building's time zone (``tours.timezone``)."""
    return ZoneInfo(request.app[SERVICES].cfg.tours.timezone)


def local_time(wall_s: float, tz: ZoneInfo) -> str:
    """UNIX seconds → ``2025-06-02T10:30:05+01:00`` in ``tz``."""
    return dt.datetime.fromtimestamp(wall_s, tz).isoformat(timespec="seconds")


def json_ok(data: Any, status: int = 200) -> web.Response:
    """A JSON response through the project's encoder (dataclasses, numpy, NaN as null)."""
    return web.json_response(data, status=status, dumps=to_json)


def present(value: T | None, why: str) -> T:
    """``value``, or 503 saying ``why`` this rover has no such thing (a part that is off)."""
    if value is None:
        raise http_error(web.HTTPServiceUnavailable, why)
    return value
