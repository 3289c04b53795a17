"""The tour data model: named tours of ordered stops, validated, as plain JSON.

A :class:`Tour` has an id (never reused), a name, a revision (bumped by every change, so two
operators editing at once are told instead of overwriting each other) and ordered
:class:`TourStop`\\ s. A stop has a name, a pose in ``map`` (metres; an optional heading in
radians, REP-103: counter-clockwise from +x), a dwell time in seconds, a visitor
:class:`Message` (text, optional language and voice) and an optional route: the id of a path
of the path manager whose waypoints the rover follows on its way *to* this stop.

Everything here is immutable and pure: validation raises :class:`TourError` whose message is
one sentence naming the value, what is wrong and what is allowed. Placement on the map (outside
the map, inside a wall) is checked by the store through an injected checker
(``curio/tours/placement.py``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from typing import Any

__all__ = [
    "MAX_DWELL_S",
    "MAX_MESSAGE_CHARS",
    "MAX_NAME_CHARS",
    "MAX_STOPS",
    "Message",
    "Tour",
    "TourError",
    "TourStop",
    "check_name",
    "make_message",
    "make_stop",
    "stop_from_json",
    "tour_from_json",
]

MAX_NAME_CHARS = 60
MAX_STOPS = 100
MAX_DWELL_S = 3600.0
MAX_MESSAGE_CHARS = 1000
MAX_COORD_M = 10_000.0
_LANGUAGE = re.compile(r"^[a-z]{2,3}(-[A-Za-z0-9]{2,8})*$")
_VOICE = re.compile(r"^[A-Za-z0-9_+.\-]{1,40}$")


class TourError(ValueError):
    """A tour, stop or schedule that cannot be accepted; ``str()`` is a sentence for people."""


@dataclass(frozen=True, slots=True)
class Message:
    """What the rover says and the kiosk shows at a stop.

    Attributes:
        text: the words ("" = nothing is said).
        language: a BCP-47 language tag (``en``, ``fr``, ``pt-BR``); "" = the speech
            engine's default.
        voice: a voice of the speech engine (espeak-ng: ``en-gb+f3``); "" = chosen by
            ``language``.
    """

    text: str = ""
    language: str = ""
    voice: str = ""

    def to_json(self) -> dict[str, str]:
        """JSON-safe form."""
        return {"text": self.text, "language": self.language, "voice": self.voice}


@dataclass(frozen=True, slots=True)
class TourStop:
    """One stop of a tour, in ``map`` (metres, radians)."""

    name: str
    x_m: float
    y_m: float
    yaw_rad: float | None = None
    dwell_s: float = 10.0
    message: Message = Message()
    route_path_id: int | None = None

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form (the file and the dashboard)."""
        return {"name": self.name, "x_m": self.x_m, "y_m": self.y_m, "yaw_rad": self.yaw_rad,
                "dwell_s": self.dwell_s, "message": self.message.to_json(),
                "route_path_id": self.route_path_id}


@dataclass(frozen=True, slots=True)
class Tour:
    """A named tour: ``id`` (never reused), ``name``, ``revision`` and ordered ``stops``;
    ``kiosk``: offered to visitors on the kiosk page (a draft is not)."""

    id: int
    name: str
    stops: tuple[TourStop, ...] = ()
    revision: int = 1
    kiosk: bool = True

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form (the file and the dashboard)."""
        return {"id": self.id, "name": self.name, "revision": self.revision,
                "kiosk": self.kiosk, "stops": [s.to_json() for s in self.stops]}

    def bumped(self, **changes: Any) -> Tour:
        """A copy with ``changes`` and the next revision."""
        return replace(self, revision=self.revision + 1, **changes)


def check_name(value: Any, what: str = "a tour name") -> str:
    """A clean name (blanks collapsed), or :class:`TourError`."""
    if not isinstance(value, str):
        raise TourError(f"{what} must be text, got {value!r}.")
    name = " ".join(value.split())
    if not name:
        raise TourError(f"{what} cannot be empty.")
    if len(name) > MAX_NAME_CHARS:
        raise TourError(f"{what} can have at most {MAX_NAME_CHARS} characters "
                        f"(this one has {len(name)}).")
    return name


def _number(value: Any, what: str, low: float, high: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TourError(f"{what} must be a number of {unit}, got {value!r}.")
    number = float(value)
    if not math.isfinite(number) or not low <= number <= high:
        raise TourError(f"{what} must be a number of {unit} from {low:g} to {high:g}, "
                        f"got {value!r}.")
    return number


def _yaw(value: Any) -> float | None:
    if value is None:
        return None
    number = _number(value, "the heading", -1e6, 1e6, "radians")
    return round(math.remainder(number, 2.0 * math.pi), 6)


def make_message(text: Any = "", language: Any = "", voice: Any = "") -> Message:
    """A validated :class:`Message` (blanks in ``text`` collapsed)."""
    if not isinstance(text, str):
        raise TourError(f"a visitor message must be text, got {text!r}.")
    clean = " ".join(text.split())
    if len(clean) > MAX_MESSAGE_CHARS:
        raise TourError(f"a visitor message can have at most {MAX_MESSAGE_CHARS} characters "
                        f"(this one has {len(clean)}).")
    if not isinstance(language, str) or (language and not _LANGUAGE.match(language)):
        raise TourError(f"the message language must be a language tag such as 'en', 'fr' or "
                        f"'pt-BR' (or empty), got {language!r}.")
    if not isinstance(voice, str) or (voice and not _VOICE.match(voice)):
        raise TourError(f"the voice must be a speech-engine voice name such as 'en-gb+f3' "
                        f"(letters, digits, + - _ . ; at most 40), or empty, got {voice!r}.")
    return Message(clean, language, voice)


def make_stop(name: Any, x_m: Any, y_m: Any, yaw_rad: Any = None, dwell_s: Any = 10.0,
              message: Message | None = None, route_path_id: Any = None) -> TourStop:
    """A validated :class:`TourStop` (coordinates rounded to 0.1 mm, heading wrapped)."""
    route = route_path_id
    if route is not None and (isinstance(route, bool) or not isinstance(route, int)
                              or route < 0):
        raise TourError(f"a stop's route must be a path number (0 or more) or empty, "
                        f"got {route!r}.")
    return TourStop(
        name=check_name(name, "a stop name"),
        x_m=round(_number(x_m, "x", -MAX_COORD_M, MAX_COORD_M, "metres"), 4),
        y_m=round(_number(y_m, "y", -MAX_COORD_M, MAX_COORD_M, "metres"), 4),
        yaw_rad=_yaw(yaw_rad),
        dwell_s=_number(dwell_s, "the dwell time", 0.0, MAX_DWELL_S, "seconds"),
        message=message if message is not None else Message(),
        route_path_id=route,
    )


def stop_from_json(item: Any) -> TourStop:
    """A stop from its JSON form (the current file version)."""
    if not isinstance(item, dict):
        raise TourError(f"a stop must be an object, got {item!r}.")
    msg = item.get("message", {})
    if isinstance(msg, str):
        message = make_message(msg)
    elif isinstance(msg, dict):
        message = make_message(msg.get("text", ""), msg.get("language", ""),
                               msg.get("voice", ""))
    else:
        raise TourError(f"a stop's message must be text or an object, got {msg!r}.")
    try:
        return make_stop(item["name"], item["x_m"], item["y_m"], item.get("yaw_rad"),
                         item.get("dwell_s", 10.0), message, item.get("route_path_id"))
    except KeyError as exc:
        raise TourError(f"a stop has no {exc.args[0]!r}.") from None


def tour_from_json(item: Any) -> Tour:
    """A tour from its JSON form (the current file version)."""
    if not isinstance(item, dict):
        raise TourError(f"a tour must be an object, got {item!r}.")
    tour_id, revision = item.get("id"), item.get("revision", 1)
    if isinstance(tour_id, bool) or not isinstance(tour_id, int) or tour_id < 1:
        raise TourError(f"a tour id must be a whole number of 1 or more, got {tour_id!r}.")
    if isinstance(revision, bool) or not isinstance(revision, int) or revision < 1:
        raise TourError(f"tour {tour_id}: the revision must be a whole number of 1 or more, "
                        f"got {revision!r}.")
    stops = item.get("stops", [])
    if not isinstance(stops, list) or len(stops) > MAX_STOPS:
        raise TourError(f"tour {tour_id}: stops must be a list of at most {MAX_STOPS}.")
    parsed: list[TourStop] = []
    for i, stop in enumerate(stops):
        try:
            parsed.append(stop_from_json(stop))
        except TourError as exc:
            raise TourError(f"tour {tour_id}, stop {i + 1}: {exc}") from None
    kiosk = item.get("kiosk", True)
    if not isinstance(kiosk, bool):
        raise TourError(f"tour {tour_id}: 'kiosk' must be true or false, got {kiosk!r}.")
    return Tour(tour_id, check_name(item.get("name")), tuple(parsed), revision, kiosk)
