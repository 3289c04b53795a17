"""Schedules: which tour runs at which local times on which weekdays, and closed days.

A :class:`Schedule` says "tour 2 at 10:00 and 14:00 on Monday to Friday" in the building's time
zone (``tours.timezone``, an IANA name; ``zoneinfo`` handles summer time: a time that does not
exist on the day the clocks go forward runs at the shifted instant Python gives it). Closed
days (:class:`ClosedDay`, a date and a note) cancel every schedule on that date. Schedules are
kept in ``<data_dir>/schedules.json`` like the tours (``curio/tours/files.py``).

Overlap is refused: two scheduled tours on the same weekday must start at least the first one's
estimated duration (the injected ``duration_of``, seconds: legs, dwell and the way home) plus
``tours.schedule_gap_s`` apart — within one schedule and across schedules. Tours just before
midnight are not compared with the next morning's.
"""

from __future__ import annotations

import datetime as dt
import logging
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

from .files import VersionedFile
from .model import TourError

__all__ = ["WEEKDAYS", "ClosedDay", "Occurrence", "Schedule", "ScheduleStore", "parse_day"]

log = logging.getLogger("curio.tours.schedule")

FILE_VERSION = 1
MAX_SCHEDULES = 200
MAX_TIMES = 48
WEEKDAYS = ("mon", "tue", "wed", "thu", "fri", "sat", "sun")
DAY_NAMES = ("Monday", "Tuesday", "Wednesday", "Thursday", "Friday", "Saturday", "Sunday")
DAY_GROUPS = {"daily": WEEKDAYS, "weekdays": WEEKDAYS[:5], "weekend": WEEKDAYS[5:]}
_TIME = re.compile(r"^([01]?\d|2[0-3]):([0-5]\d)$")


@dataclass(frozen=True, slots=True)
class Schedule:
    """Tour ``tour_id`` at each of ``times`` (local ``HH:MM``) on each of ``days``."""

    id: int
    tour_id: int
    days: tuple[str, ...]
    times: tuple[str, ...]
    enabled: bool = True
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form (the file and the dashboard)."""
        return {"id": self.id, "tour_id": self.tour_id, "days": list(self.days),
                "times": list(self.times), "enabled": self.enabled, "note": self.note}


@dataclass(frozen=True, slots=True)
class ClosedDay:
    """A date (local, ISO ``YYYY-MM-DD``) on which no scheduled tour runs."""

    date: str
    note: str = ""

    def to_json(self) -> dict[str, str]:
        """JSON-safe form."""
        return {"date": self.date, "note": self.note}


@dataclass(frozen=True, slots=True)
class Occurrence:
    """One scheduled start: schedule, tour, local time and UNIX time (seconds)."""

    schedule_id: int
    tour_id: int
    local: dt.datetime
    wall_s: float

    @property
    def label(self) -> str:
        """``Mon 2025-06-02 10:00`` (local time)."""
        return self.local.strftime("%a %Y-%m-%d %H:%M")

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"schedule_id": self.schedule_id, "tour_id": self.tour_id,
                "local": self.local.isoformat(), "wall_s": self.wall_s}


def _days(value: Any) -> tuple[str, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list | tuple) or not items:
        raise TourError(f"days must be a list of weekdays (mon .. sun, or daily, weekdays, "
                        f"weekend), got {value!r}.")
    out: set[str] = set()
    for item in items:
        key = item.strip().lower()[:3] if isinstance(item, str) else None
        word = item.strip().lower() if isinstance(item, str) else ""
        if word in DAY_GROUPS:
            out.update(DAY_GROUPS[word])
        elif key in WEEKDAYS and DAY_NAMES[WEEKDAYS.index(key)].lower().startswith(word):
            out.add(key)
        else:
            raise TourError(f"{item!r} is not a weekday; use mon, tue, wed, thu, fri, sat, sun "
                            "(or daily, weekdays, weekend).")
    return tuple(d for d in WEEKDAYS if d in out)


def _times(value: Any) -> tuple[str, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list | tuple) or not items or len(items) > MAX_TIMES:
        raise TourError(f"times must be a list of 1 to {MAX_TIMES} local times HH:MM, "
                        f"got {value!r}.")
    out = set()
    for item in items:
        match = _TIME.match(item.strip()) if isinstance(item, str) else None
        if match is None:
            raise TourError(f"{item!r} is not a time of day; use HH:MM from 00:00 to 23:59.")
        out.add(f"{int(match[1]):02d}:{match[2]}")
    return tuple(sorted(out))


def parse_day(value: Any) -> dt.date:
    """An ISO date ``YYYY-MM-DD`` (:class:`TourError` otherwise)."""
    try:
        if not isinstance(value, str):
            raise ValueError
        return dt.date.fromisoformat(value.strip())
    except ValueError:
        raise TourError(f"{value!r} is not a date; use YYYY-MM-DD, e.g. 2025-12-25.") from None


def _minutes(hhmm: str) -> int:
    hours, minutes = hhmm.split(":")
    return int(hours) * 60 + int(minutes)


def _fmt_minutes(seconds: float) -> str:
    return f"{max(1, round(seconds / 60.0))} min"


class ScheduleStore:
    """Schedules and closed days, validated (overlap included) and persisted.

    Args:
        file: ``<data_dir>/schedules.json`` (None: in memory).
        timezone: the building's zone.
        duration_of: a tour's estimated duration in seconds (legs, dwell, way home).
        tour_problem: why a tour cannot be scheduled (unknown, no stops), or None.
        gap_s: ``tours.schedule_gap_s``.
        tour_label: how a refusal names a tour (default ``tour 2``).

    Raises:
        DataFileError: the file exists but cannot be used (it is left as it is).
    """

    def __init__(self, file: Path | None, timezone: ZoneInfo,
                 duration_of: Callable[[int], float],
                 tour_problem: Callable[[int], str | None] = lambda _id: None,
                 gap_s: float = 300.0,
                 tour_label: Callable[[int], str] = lambda tid: f"tour {tid}") -> None:
        self.tz = timezone
        self.tour_label = tour_label
        self.duration_of = duration_of
        self.tour_problem = tour_problem
        self.gap_s = gap_s
        self._file = VersionedFile(file, "schedules", FILE_VERSION) if file else None
        self._schedules: dict[int, Schedule] = {}
        self._closed: dict[str, ClosedDay] = {}
        self._next_id = 1
        self._listeners: list[Callable[[str, int, str], None]] = []
        self._load()
        self._saved = self._state()  # the last state on disk

    # --- persistence ------------------------------------------------------------------------

    def _load(self) -> None:
        loaded = self._file.load_recovering(self._parse_file) if self._file is not None \
            else None
        if loaded is None:
            self._save()
            return
        self._schedules, self._closed, self._next_id = loaded

    def _parse_file(self, data: dict[str, Any]) -> tuple[
            dict[int, Schedule], dict[str, ClosedDay], int]:
        """The schedules, closed days and next id of a loaded file (raises its error)."""
        assert self._file is not None
        schedules: dict[int, Schedule] = {}
        closed: dict[str, ClosedDay] = {}
        try:
            for item in data.get("schedules", []):
                sched = self._parse(item)
                if sched.id in schedules:
                    raise TourError(f"schedule id {sched.id} repeats")
                schedules[sched.id] = sched
            for item in data.get("closed", []):
                day = parse_day(item.get("date") if isinstance(item, dict) else item)
                note = item.get("note", "") if isinstance(item, dict) else ""
                closed[day.isoformat()] = ClosedDay(day.isoformat(), str(note))
        except (TourError, AttributeError, TypeError) as exc:
            raise self._file.error(str(exc)) from None
        next_id = data.get("next_id", 1)
        if isinstance(next_id, bool) or not isinstance(next_id, int):
            raise self._file.error(f"next_id must be a whole number, got {next_id!r}")
        return schedules, closed, max([next_id, *[i + 1 for i in schedules]])

    @property
    def restored(self) -> str | None:
        """What was done at load when the file could not be used (its backup was put in
        its place), or None."""
        return self._file.restored if self._file is not None else None

    @staticmethod
    def _parse(item: Any) -> Schedule:
        if not isinstance(item, dict):
            raise TourError(f"a schedule must be an object, got {item!r}")
        sid, tour_id = item.get("id"), item.get("tour_id")
        for what, value in (("schedule id", sid), ("tour id", tour_id)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise TourError(f"a {what} must be a whole number of 1 or more, got {value!r}")
        assert isinstance(sid, int) and isinstance(tour_id, int)
        return Schedule(sid, tour_id, _days(item.get("days")), _times(item.get("times")),
                        bool(item.get("enabled", True)), str(item.get("note", ""))[:200])

    def _save(self) -> None:
        if self._file is not None:
            self._file.save({
                "next_id": self._next_id,
                "schedules": [s.to_json() for s in self._schedules.values()],
                "closed": [c.to_json() for c in sorted(self._closed.values(),
                                                       key=lambda c: c.date)],
            })

    def add_listener(self, listener: Callable[[str, int, str], None]) -> None:
        """Call ``listener(change, schedule_id, actor)`` after every saved change (closed-day
        changes pass id 0)."""
        self._listeners.append(listener)

    def _state(self) -> tuple[dict[int, Schedule], dict[str, ClosedDay], int]:
        return dict(self._schedules), dict(self._closed), self._next_id

    def _changed(self, change: str, sid: int, actor: str) -> None:
        """Save after an edit; when the file cannot be written (a full disk) the edit is undone
        and refused with the reason, so it cannot reach the file with a later save."""
        try:
            self._save()
        except OSError as exc:
            schedules, closed, self._next_id = self._saved
            self._schedules, self._closed = dict(schedules), dict(closed)
            log.error("could not save the schedules: %s", exc)
            raise TourError(f"Could not save the schedules ({exc.strerror or exc}): nothing was "
                            "changed. Free space on the rover's disk, then try again.") from exc
        self._saved = self._state()
        for listener in list(self._listeners):
            try:
                listener(change, sid, actor)
            except Exception:  # a broken listener must not lose the edit
                log.exception("schedule listener failed")

    # --- queries ----------------------------------------------------------------------------

    def list_schedules(self) -> list[Schedule]:
        """Every schedule, by id."""
        return [self._schedules[i] for i in sorted(self._schedules)]

    def get(self, schedule_id: Any) -> Schedule:
        """Schedule ``schedule_id`` (:class:`TourError` listing the ids there are)."""
        sched = self._schedules.get(schedule_id) if isinstance(schedule_id, int) else None
        if sched is None or isinstance(schedule_id, bool):
            ids = ", ".join(str(i) for i in sorted(self._schedules)) or "none"
            raise TourError(f"There is no schedule {schedule_id!r}. The schedules are: {ids}.")
        return sched

    def for_tour(self, tour_id: int) -> list[Schedule]:
        """The schedules that run ``tour_id``."""
        return [s for s in self.list_schedules() if s.tour_id == tour_id]

    def closed_days(self) -> list[ClosedDay]:
        """Every closed day, by date."""
        return sorted(self._closed.values(), key=lambda c: c.date)

    def occurrences(self, after_wall_s: float, until_wall_s: float) -> list[Occurrence]:
        """Scheduled starts with ``after < wall_s <= until`` (enabled schedules, open days),
        in time order."""
        first = dt.datetime.fromtimestamp(after_wall_s, self.tz).date()
        last = dt.datetime.fromtimestamp(until_wall_s, self.tz).date()
        out: list[Occurrence] = []
        day = first
        while day <= last:
            out.extend(o for o in self._on_day(day) if after_wall_s < o.wall_s <= until_wall_s)
            day += dt.timedelta(days=1)
        return sorted(out, key=lambda o: (o.wall_s, o.schedule_id))

    def _on_day(self, day: dt.date) -> Iterable[Occurrence]:
        if day.isoformat() in self._closed:
            return
        weekday = WEEKDAYS[day.weekday()]
        for sched in self._schedules.values():
            if not sched.enabled or weekday not in sched.days:
                continue
            for hhmm in sched.times:
                minutes = _minutes(hhmm)
                local = dt.datetime(day.year, day.month, day.day, minutes // 60, minutes % 60,
                                    tzinfo=self.tz)
                yield Occurrence(sched.id, sched.tour_id, local, local.timestamp())

    def next_occurrence(self, after_wall_s: float, horizon_days: int = 14) -> Occurrence | None:
        """The first scheduled start after ``after_wall_s`` within ``horizon_days``."""
        upcoming = self.occurrences(after_wall_s, after_wall_s + horizon_days * 86400.0)
        return upcoming[0] if upcoming else None

    # --- validation -------------------------------------------------------------------------

    def _check_overlap(self, candidate: Schedule) -> None:
        """Refuse ``candidate`` if any two enabled starts on a weekday come too close."""
        if not candidate.enabled:
            return
        others = [s for s in self._schedules.values() if s.enabled and s.id != candidate.id]
        durations: dict[int, float] = {}

        def duration(tour_id: int) -> float:
            if tour_id not in durations:
                durations[tour_id] = float(self.duration_of(tour_id))
            return durations[tour_id]

        for day in candidate.days:
            slots = sorted(
                (_minutes(t) * 60.0, s.id, s.tour_id, t)
                for s in [*others, candidate] if day in s.days for t in s.times)
            for (start_a, sid_a, tour_a, t_a), (start_b, sid_b, tour_b, t_b) in pairwise(slots):
                if candidate.id not in (sid_a, sid_b):
                    continue
                needed = duration(tour_a) + self.gap_s
                if start_b - start_a < needed:
                    where = "this schedule" if sid_a == candidate.id else f"schedule {sid_a}"
                    raise TourError(
                        f"Overlapping schedules: on {DAY_NAMES[WEEKDAYS.index(day)]} the "
                        f"{t_b} {self.tour_label(tour_b)} would start before the {t_a} "
                        f"{self.tour_label(tour_a)} "
                        f"({where}) is over (about {_fmt_minutes(duration(tour_a))} including "
                        f"the way home, plus {_fmt_minutes(self.gap_s)} between tours); "
                        f"start it at {_hhmm(start_a + needed)} or later.")

    def _validated(self, sched: Schedule) -> Schedule:
        problem = self.tour_problem(sched.tour_id)
        if problem:
            raise TourError(f"Cannot schedule it: {problem}")
        self._check_overlap(sched)
        return sched

    # --- edits ------------------------------------------------------------------------------

    def add(self, tour_id: Any, days: Any, times: Any, *, enabled: bool = True,
            note: str = "", actor: str = "") -> Schedule:
        """Schedule ``tour_id`` at ``times`` on ``days``; refused when it overlaps another."""
        if len(self._schedules) >= MAX_SCHEDULES:
            raise TourError(f"There are already {MAX_SCHEDULES} schedules; delete one first.")
        if isinstance(tour_id, bool) or not isinstance(tour_id, int):
            raise TourError(f"a tour number must be a whole number, got {tour_id!r}.")
        sched = self._validated(Schedule(self._next_id, tour_id, _days(days), _times(times),
                                         bool(enabled), str(note)[:200]))
        self._schedules[sched.id] = sched
        self._next_id += 1
        self._changed("created", sched.id, actor)
        return sched

    def update(self, schedule_id: Any, *, actor: str = "", **fields: Any) -> Schedule:
        """Change ``tour_id``, ``days``, ``times``, ``enabled`` or ``note`` of a schedule."""
        old = self.get(schedule_id)
        allowed = {"tour_id", "days", "times", "enabled", "note"}
        unknown = sorted(set(fields) - allowed)
        if unknown:
            raise TourError(f"A schedule has no field {unknown[0]!r}; the fields are "
                            f"{', '.join(sorted(allowed))}.")
        new = replace(old, tour_id=fields.get("tour_id", old.tour_id),
                      days=_days(fields["days"]) if "days" in fields else old.days,
                      times=_times(fields["times"]) if "times" in fields else old.times,
                      enabled=bool(fields.get("enabled", old.enabled)),
                      note=str(fields.get("note", old.note))[:200])
        self._schedules[old.id] = self._validated(new)
        self._changed("changed", old.id, actor)
        return new

    def delete(self, schedule_id: Any, *, actor: str = "") -> Schedule:
        """Delete a schedule."""
        sched = self.get(schedule_id)
        del self._schedules[sched.id]
        self._changed("deleted", sched.id, actor)
        return sched

    def delete_for_tour(self, tour_id: int, *, actor: str = "") -> list[int]:
        """Delete every schedule of ``tour_id``; return their ids."""
        ids = [s.id for s in self.for_tour(tour_id)]
        for sid in ids:
            self.delete(sid, actor=actor)
        return ids

    def set_closed(self, dates: Sequence[Any], note: str = "", *, closed: bool = True,
                   actor: str = "") -> list[ClosedDay]:
        """Mark ``dates`` (``YYYY-MM-DD``) closed with ``note``, or open again."""
        days = [parse_day(d).isoformat() for d in dates]
        for day in days:
            if closed:
                self._closed[day] = ClosedDay(day, str(note)[:200])
            else:
                self._closed.pop(day, None)
        self._changed("closed" if closed else "opened", 0, actor)
        return self.closed_days()


def _hhmm(seconds: float) -> str:
    minutes = int(-(-seconds // 60))
    return f"{minutes // 60:02d}:{minutes % 60:02d}" if minutes < 24 * 60 else "the next day"
