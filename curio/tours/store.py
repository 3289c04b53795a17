"""The tour store: named tours with validated edits, persisted in ``<data_dir>/tours.json``.

Every edit is validated (names, numbers, and — through the injected ``check_place`` — that a
stop lies on the map and not inside an obstacle), bumps the tour's revision and is written
before the call returns (``curio/tours/files.py``: write-then-rename, previous good file kept as
``tours.json.bak``). An edit may name the revision it was based on (``expect_revision``); if
someone else changed the tour meanwhile it is refused instead of silently overwriting.

The first time (no file yet) the configured ``bt.tour_stops`` become tour 1, "Tour". A file
that cannot be used raises :class:`~curio.tours.files.DataFileError` (the CLI: one line,
exit 2) and is left untouched. Ids are never reused, so a stale command for a deleted tour is
refused instead of running another one.

File versions: 2 (this one) holds many tours; version 1 held one tour in the shape of
``[[bt.tour_stops]]`` (``yaw_deg``, a plain ``message``) and is migrated on load.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from curio.core.config import TourStopConfig

from .files import VersionedFile
from .model import (
    MAX_NAME_CHARS,
    MAX_STOPS,
    Message,
    Tour,
    TourError,
    TourStop,
    check_name,
    make_message,
    make_stop,
    tour_from_json,
)

__all__ = ["FILE_VERSION", "MAX_TOURS", "PlaceCheck", "TourStore", "migrate_v1"]

log = logging.getLogger("curio.tours.store")

FILE_VERSION = 2
MAX_TOURS = 200

PlaceCheck = Callable[[float, float], str | None]
"""``check(x_m, y_m)`` in ``map``: None when the rover can stand there, else the reason."""


def migrate_v1(data: dict[str, Any]) -> dict[str, Any]:
    """Version 1 (one tour, ``[[bt.tour_stops]]`` shape) → version 2 (many tours)."""
    stops = []
    for stop in data["stops"]:
        yaw_deg = stop.get("yaw_deg")
        stops.append({
            "name": stop["name"], "x_m": stop["x_m"], "y_m": stop["y_m"],
            "yaw_rad": None if yaw_deg is None else math.radians(float(yaw_deg)),
            "dwell_s": stop.get("dwell_s", 10.0),
            "message": {"text": stop.get("message", ""), "language": "", "voice": ""},
            "route_path_id": None,
        })
    tour = {"id": 1, "name": data.get("name") or "Tour", "revision": 1, "stops": stops}
    return {"next_id": 2, "tours": [tour]}


def stops_from_config(stops: Sequence[TourStopConfig]) -> tuple[TourStop, ...]:
    """``bt.tour_stops`` as tour stops (headings from degrees)."""
    return tuple(
        make_stop(s.name, s.x_m, s.y_m,
                  math.radians(s.yaw_deg) if s.yaw_deg is not None else None,
                  s.dwell_s, make_message(s.message))
        for s in stops)


class TourStore:
    """Tours by id, in their list order, with validated and persisted edits.

    Args:
        file: where they are kept (None: in memory, for tests and benchmarks).
        seed: ``bt.tour_stops``: tour 1 when there is no file yet.
        check_place: tells whether the rover can stand at a point (None: not checked).
        path_exists: tells whether a path of the path manager exists (None: not checked).

    Raises:
        DataFileError: the file exists but cannot be used (it is left as it is).
    """

    def __init__(self, file: Path | None = None, seed: Sequence[TourStopConfig] = (),
                 check_place: PlaceCheck | None = None,
                 path_exists: Callable[[int], bool] | None = None) -> None:
        self.check_place = check_place
        self.path_exists = path_exists
        self._file = VersionedFile(file, "tours", FILE_VERSION, {1: migrate_v1}) \
            if file is not None else None
        self._tours: dict[int, Tour] = {}
        self._next_id = 1
        self._listeners: list[Callable[[str, int, str], None]] = []
        self._load(seed)
        self._saved = (dict(self._tours), self._next_id)  # the last state on disk

    # --- persistence ------------------------------------------------------------------------

    def _load(self, seed: Sequence[TourStopConfig]) -> None:
        loaded = self._file.load_recovering(self._parse) if self._file is not None else None
        if loaded is None:
            if seed:
                self._tours[1] = Tour(1, "Tour", stops_from_config(seed))
                self._next_id = 2
            self._save()
            return
        self._tours, self._next_id = loaded

    def _parse(self, data: dict[str, Any]) -> tuple[dict[int, Tour], int]:
        """The tours and the next id of a loaded file (raises the file's error)."""
        assert self._file is not None
        try:
            tours = [tour_from_json(t) for t in data.get("tours", [])]
        except TourError as exc:
            raise self._file.error(str(exc)) from None
        ids = [t.id for t in tours]
        if len(set(ids)) != len(ids):
            raise self._file.error(f"tour ids repeat ({ids})")
        next_id = data.get("next_id", 1)
        if isinstance(next_id, bool) or not isinstance(next_id, int):
            raise self._file.error(f"next_id must be a whole number, got {next_id!r}")
        return {t.id: t for t in tours}, max([next_id, *[i + 1 for i in ids]])

    @property
    def restored(self) -> str | None:
        """What was done at load when the file could not be used (its backup was put in
        its place), or None."""
        return self._file.restored if self._file is not None else None

    def _save(self) -> None:
        if self._file is not None:
            self._file.save({"next_id": self._next_id,
                             "tours": [t.to_json() for t in self._tours.values()]})

    @property
    def file(self) -> Path | None:
        """Where the tours are kept (None: in memory)."""
        return self._file.path if self._file is not None else None

    def add_listener(self, listener: Callable[[str, int, str], None]) -> None:
        """Call ``listener(change, tour_id, actor)`` after every saved change."""
        self._listeners.append(listener)

    def _changed(self, change: str, tour: Tour, actor: str) -> Tour:
        """Save after an edit; when the file cannot be written (a full disk) the edit is undone
        and refused with the reason, so it cannot reach the file with a later save."""
        try:
            self._save()
        except OSError as exc:
            self._tours, self._next_id = dict(self._saved[0]), self._saved[1]
            log.error("could not save the tours: %s", exc)
            raise TourError(f"Could not save the tours ({exc.strerror or exc}): nothing was "
                            "changed. Free space on the rover's disk, then try again.") from exc
        self._saved = (dict(self._tours), self._next_id)
        for listener in list(self._listeners):
            try:
                listener(change, tour.id, actor)
            except Exception:  # a broken listener must not lose the edit
                log.exception("tour listener failed")
        return tour

    # --- queries ----------------------------------------------------------------------------

    def list_tours(self) -> list[Tour]:
        """Every tour, in list order."""
        return list(self._tours.values())

    def describe(self) -> str:
        """``1 (Highlights), 2 (North wing)`` for messages."""
        return ", ".join(f"{t.id} ({t.name})" for t in self._tours.values()) or "none"

    def get(self, tour_id: Any) -> Tour:
        """The tour ``tour_id``; :class:`TourError` listing the tours there are."""
        if isinstance(tour_id, bool) or not isinstance(tour_id, int):
            raise TourError(f"a tour number must be a whole number, got {tour_id!r}.")
        tour = self._tours.get(tour_id)
        if tour is None:
            raise TourError(f"There is no tour {tour_id}. The tours are: {self.describe()}.")
        return tour

    def first(self) -> Tour | None:
        """The first tour of the list (the one a plain Start tour runs), or None."""
        return next(iter(self._tours.values()), None)

    def place_problem(self, x_m: float, y_m: float) -> str | None:
        """Why the rover cannot stand at (x, y), or None (also None without a checker)."""
        return self.check_place(x_m, y_m) if self.check_place is not None else None

    def problems(self, tour: Tour) -> list[str]:
        """What stops ``tour`` from running: no stops, stops off the map or in an obstacle,
        routes that name a deleted path. Empty when it can run."""
        out = [] if tour.stops else [f"Tour {tour.id} ({tour.name}) has no stops; add at "
                                     "least one."]
        for i, stop in enumerate(tour.stops):
            why = self.place_problem(stop.x_m, stop.y_m)
            if why:
                out.append(f"Stop {i + 1} ({stop.name}) {why}.")
            if (stop.route_path_id is not None and self.path_exists is not None
                    and not self.path_exists(stop.route_path_id)):
                out.append(f"Stop {i + 1} ({stop.name}) follows path {stop.route_path_id}, "
                           "which no longer exists.")
        return out

    def schedule_problem(self, tour_id: int) -> str | None:
        """Why ``tour_id`` cannot be scheduled (unknown, no stops), or None."""
        try:
            tour = self.get(tour_id)
        except TourError as exc:
            return str(exc)
        if not tour.stops:
            return f"Tour {tour.id} ({tour.name}) has no stops; add stops before scheduling it."
        return None

    # --- checks used by edits ---------------------------------------------------------------

    def _editable(self, tour_id: Any, expect_revision: int | None) -> Tour:
        tour = self.get(tour_id)
        if expect_revision is not None and expect_revision != tour.revision:
            raise TourError(f"Tour {tour.id} ({tour.name}) was changed meanwhile (revision "
                            f"{tour.revision}, your edit was based on {expect_revision}); "
                            "reload it and edit again.")
        return tour

    def _unique_name(self, name: Any, except_id: int | None = None) -> str:
        clean = check_name(name)
        for other in self._tours.values():
            if other.id != except_id and other.name.casefold() == clean.casefold():
                raise TourError(f"There is already a tour called '{other.name}' (tour "
                                f"{other.id}); choose another name.")
        return clean

    def _placed(self, stop: TourStop) -> TourStop:
        why = self.place_problem(stop.x_m, stop.y_m)
        if why:
            raise TourError(f"The stop '{stop.name}' at ({stop.x_m:g}, {stop.y_m:g}) m {why}; "
                            "put it where the rover can stand.")
        if (stop.route_path_id is not None and self.path_exists is not None
                and not self.path_exists(stop.route_path_id)):
            raise TourError(f"There is no path {stop.route_path_id} to follow to the stop "
                            f"'{stop.name}'.")
        return stop

    @staticmethod
    def _index(tour: Tour, index: Any, *, inserting: bool = False) -> int:
        n = len(tour.stops) + (1 if inserting else 0)
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < n:
            if n == 0:
                raise TourError(f"Tour {tour.id} ({tour.name}) has no stops.")
            raise TourError(f"Tour {tour.id} ({tour.name}) has stops 0 to {n - 1}; there is "
                            f"no stop {index!r}.")
        return index

    # --- edits ------------------------------------------------------------------------------

    def create(self, name: Any, stops: Sequence[TourStop] = (), *, kiosk: bool = True,
               actor: str = "") -> Tour:
        """Create a tour (it may be empty: stops are added one by one) at the end of the list;
        ``kiosk``: offered to visitors at the kiosk."""
        if len(self._tours) >= MAX_TOURS:
            raise TourError(f"There are already {MAX_TOURS} tours; delete one first.")
        if len(stops) > MAX_STOPS:
            raise TourError(f"A tour can have at most {MAX_STOPS} stops.")
        if not isinstance(kiosk, bool):
            raise TourError(f"'kiosk' (offered at the kiosk) must be true or false, got "
                            f"{kiosk!r}.")
        tour = Tour(self._next_id, self._unique_name(name),
                    tuple(self._placed(s) for s in stops), kiosk=kiosk)
        self._tours[tour.id] = tour
        self._next_id += 1
        return self._changed("created", tour, actor)

    def _put(self, tour: Tour, change: str, actor: str) -> Tour:
        self._tours[tour.id] = tour
        return self._changed(change, tour, actor)

    def upsert(self, tour: Tour, *, actor: str = "") -> Tour:
        """Keep ``tour`` under its own id and revision, replacing the tour with that id (a
        tour distributed by the fleet manager, ``curio/fleet``); its stops are checked like
        any edit and its name must not be another tour's. Unchanged: nothing is written."""
        old = self._tours.get(tour.id)
        if old is not None and old == tour:
            return old
        if old is None and len(self._tours) >= MAX_TOURS:
            raise TourError(f"There are already {MAX_TOURS} tours; delete one first.")
        placed = Tour(tour.id, self._unique_name(tour.name, tour.id),
                      tuple(self._placed(s) for s in tour.stops), tour.revision)
        self._next_id = max(self._next_id, tour.id + 1)
        return self._put(placed, "created" if old is None else "replaced", actor)

    def rename(self, tour_id: Any, name: Any, *, expect_revision: int | None = None,
               actor: str = "") -> Tour:
        """Rename a tour."""
        tour = self._editable(tour_id, expect_revision)
        return self._put(tour.bumped(name=self._unique_name(name, tour.id)), "renamed", actor)

    def set_kiosk(self, tour_id: Any, offered: Any, *, expect_revision: int | None = None,
                  actor: str = "") -> Tour:
        """Offer a tour to visitors at the kiosk, or stop offering it."""
        tour = self._editable(tour_id, expect_revision)
        if not isinstance(offered, bool):
            raise TourError(f"'kiosk' (offered at the kiosk) must be true or false, got "
                            f"{offered!r}.")
        return self._put(tour.bumped(kiosk=offered), "kiosk", actor)

    def duplicate(self, tour_id: Any, name: Any = None, *, actor: str = "") -> Tour:
        """A copy of a tour with a new id, named ``name`` or "<name> (copy)"; the copy is not
        offered at the kiosk until an operator says so (it is a draft)."""
        tour = self.get(tour_id)
        if name is None:
            base = tour.name[:MAX_NAME_CHARS - 9]
            taken = {t.name.casefold() for t in self._tours.values()}
            name = f"{base} (copy)"
            n = 2
            while name.casefold() in taken:
                name = f"{base} (copy {n})"
                n += 1
        return self.create(name, tour.stops, kiosk=False, actor=actor)

    def delete(self, tour_id: Any, *, actor: str = "") -> Tour:
        """Delete a tour (its id is never given to another). The service refuses running or
        scheduled tours first (``curio/tours/service.py``)."""
        tour = self.get(tour_id)
        del self._tours[tour.id]
        return self._changed("deleted", tour, actor)

    def add_stop(self, tour_id: Any, stop: TourStop, index: int | None = None, *,
                 expect_revision: int | None = None, actor: str = "") -> Tour:
        """Insert ``stop`` before ``index`` (None: append)."""
        tour = self._editable(tour_id, expect_revision)
        if len(tour.stops) >= MAX_STOPS:
            raise TourError(f"Tour {tour.id} ({tour.name}) already has {MAX_STOPS} stops, the "
                            "most a tour can have.")
        at = len(tour.stops) if index is None else self._index(tour, index, inserting=True)
        stops = list(tour.stops)
        stops.insert(at, self._placed(stop))
        return self._put(tour.bumped(stops=tuple(stops)), "stop_added", actor)

    def update_stop(self, tour_id: Any, index: Any, *, expect_revision: int | None = None,
                    actor: str = "", **fields: Any) -> Tour:
        """Change fields of stop ``index``: ``name``, ``x_m``, ``y_m``, ``yaw_rad``,
        ``dwell_s``, ``message`` (a :class:`Message` or its text), ``language``, ``voice``,
        ``route_path_id`` (moving a stop is an update of ``x_m``/``y_m``/``yaw_rad``)."""
        tour = self._editable(tour_id, expect_revision)
        i = self._index(tour, index)
        old = tour.stops[i]
        allowed = {"name", "x_m", "y_m", "yaw_rad", "dwell_s", "message", "language", "voice",
                   "route_path_id"}
        unknown = sorted(set(fields) - allowed)
        if unknown:
            raise TourError(f"A stop has no field {unknown[0]!r}; the fields are "
                            f"{', '.join(sorted(allowed))}.")
        msg = fields.get("message", old.message)
        message = msg if isinstance(msg, Message) else make_message(
            msg, fields.get("language", old.message.language),
            fields.get("voice", old.message.voice))
        if isinstance(msg, Message) and ("language" in fields or "voice" in fields):
            message = make_message(msg.text, fields.get("language", msg.language),
                                   fields.get("voice", msg.voice))
        new = make_stop(fields.get("name", old.name), fields.get("x_m", old.x_m),
                        fields.get("y_m", old.y_m), fields.get("yaw_rad", old.yaw_rad),
                        fields.get("dwell_s", old.dwell_s), message,
                        fields.get("route_path_id", old.route_path_id))
        if (new.x_m, new.y_m, new.route_path_id) != (old.x_m, old.y_m, old.route_path_id):
            self._placed(new)
        stops = list(tour.stops)
        stops[i] = new
        return self._put(tour.bumped(stops=tuple(stops)), "stop_changed", actor)

    def remove_stop(self, tour_id: Any, index: Any, *, expect_revision: int | None = None,
                    actor: str = "") -> Tour:
        """Remove stop ``index``."""
        tour = self._editable(tour_id, expect_revision)
        i = self._index(tour, index)
        stops = tour.stops[:i] + tour.stops[i + 1:]
        return self._put(tour.bumped(stops=stops), "stop_removed", actor)

    def reorder(self, tour_id: Any, order: Any, *, expect_revision: int | None = None,
                actor: str = "") -> Tour:
        """Put the stops in ``order``, a permutation of their indices (``[2, 0, 1]``: the old
        third stop first)."""
        tour = self._editable(tour_id, expect_revision)
        n = len(tour.stops)
        if (not isinstance(order, list | tuple)
                or sorted(order) != list(range(n))
                or any(isinstance(i, bool) for i in order)):
            raise TourError(f"A new order for tour {tour.id} ({tour.name}) must list each of "
                            f"its stop numbers 0 to {n - 1} once, got {order!r}.")
        stops = tuple(tour.stops[i] for i in order)
        return self._put(tour.bumped(stops=stops), "reordered", actor)

    def move_stop(self, tour_id: Any, from_index: Any, to_index: Any, *,
                  expect_revision: int | None = None, actor: str = "") -> Tour:
        """Move one stop to another place in the order (drag and drop in a list)."""
        tour = self._editable(tour_id, expect_revision)
        src, dst = self._index(tour, from_index), self._index(tour, to_index)
        order = list(range(len(tour.stops)))
        order.insert(dst, order.pop(src))
        return self.reorder(tour.id, order, actor=actor)
