"""Key expressions of the fleet and their matching rules.

Every rover publishes under ``curio/<rover>/<topic>`` (``pose``, ``status``, ``battery``,
``plan``, ``health``, ``events``, ``tour``, ``scan``, ``traffic``, ``reply``), takes commands on
``curio/<rover>/cmd``, answers queries on ``curio/<rover>/q/<what>`` (``map``, ``paths``,
``tours``, ``plan``) and holds the liveliness token ``curio/<rover>/alive`` while its session
is up. The fleet manager holds ``curio/@fleet/manager`` (a verbatim chunk: never matched by
``*``), answers ``curio/@fleet/q/<what>``. In the simulator the rovers also share their true
pose on ``curio/<rover>/sim/truth`` so that separate processes can see each other.

Matching follows Zenoh's rules for the subset used here: ``*`` matches exactly one chunk
(never an ``@`` chunk), ``**`` any number of chunks (zero included).
"""

from __future__ import annotations

import re
from functools import lru_cache

__all__ = [
    "MANAGER_TOKEN",
    "ROOT",
    "ROVER_TOPICS",
    "check_rover_name",
    "keyexpr_intersects",
    "rover_key",
    "rover_of",
]

ROOT = "curio"
MANAGER_TOKEN = f"{ROOT}/@fleet/manager"
MANAGER_QUERY = f"{ROOT}/@fleet/q"
# What a rover publishes (the manager subscribes to the ones it needs).
ROVER_TOPICS: tuple[str, ...] = ("pose", "status", "battery", "plan", "health", "events",
                                 "tour", "scan", "traffic", "reply")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,31}$")
NAME_RULE = "1-32 letters, digits, '-' or '_', starting with a letter or digit"


def check_rover_name(name: str) -> str:
    """Return ``name`` if it can be a rover's key chunk.

    Raises:
        ValueError: naming the value and what is allowed.
    """
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(f"rover name {name!r} is not allowed: use {NAME_RULE}")
    return name


def rover_key(rover: str, topic: str) -> str:
    """``curio/<rover>/<topic>`` (``topic`` may have several chunks, e.g. ``q/map``)."""
    return f"{ROOT}/{rover}/{topic}"


def rover_of(key: str) -> str | None:
    """The rover chunk of ``curio/<rover>/...`` (None for other keys and the manager's)."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != ROOT or parts[1].startswith("@"):
        return None
    return parts[1]


@lru_cache(maxsize=4096)
def keyexpr_intersects(a: str, b: str) -> bool:
    """Whether key expressions ``a`` and ``b`` have a key in common (``*``, ``**``)."""
    return _match(tuple(a.split("/")), tuple(b.split("/")))


def _chunk_match(x: str, y: str) -> bool:
    if x == y:
        return True
    if x == "*":
        return not y.startswith("@")
    if y == "*":
        return not x.startswith("@")
    return False


def _match(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    if not a and not b:
        return True
    if a and a[0] == "**":
        if _match(a[1:], b):
            return True
        return bool(b) and not b[0].startswith("@") and _match(a, b[1:])
    if b and b[0] == "**":
        return _match(b, a)
    if not a or not b:
        return False
    return _chunk_match(a[0], b[0]) and _match(a[1:], b[1:])
