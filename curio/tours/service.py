"""The tour service: what the dashboard, the kiosk and the scheduler call.

One object in front of the tour store, the schedule store and the bus, with the rules that need
more than one of them. Every method is synchronous, returns plain data (or raises
:class:`~curio.tours.model.TourError` whose message is a sentence for the operator), so an HTTP
handler is a thin translation: TourError → 400 with the message, a result → JSON. The caller's
role is checked by the web layer (operators edit, the kiosk only starts and stops tours);
``actor`` names who did it for the event log.

Rules decided here:

* **Deleting a tour that is running** is refused ("stop it first") unless ``force``: then the
  tour is stopped (``stop_tour``) and deleted; the rover stops where it is, as after Stop tour.
  Deleting a scheduled tour likewise needs ``force``, which removes its schedules too.
* **Editing a tour that is running** is allowed: the rover finishes the run with the stops it
  started with (the tree holds a copy); the edit applies from the next run.
* **Starting** a tour checks what the tree cannot know cheaply: the tour exists, has stops, and
  every stop can be reached on the map; then ``start_tour`` goes on ``/operator`` like the
  dashboard's button and the tree answers with ``bt.command_accepted``/``rejected`` carrying the
  returned ``request_id`` (e-stop, pause and low battery are the tree's to refuse).

Duration estimates (:func:`estimate`) are straight legs × ``tours.estimate_detour_factor`` at
``tours.estimate_speed_mps`` plus the dwell times, from home and back home.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import ToursConfig
from curio.core.geometry import Pose2D
from curio.core.messages import Event, OperatorCommand, TourState
from curio.core.topics import EVENTS, OPERATOR, TOUR

from .model import Tour, TourError, stop_from_json
from .schedule import Occurrence, Schedule, ScheduleStore
from .store import TourStore

__all__ = ["TourEstimate", "TourService", "estimate", "route_points"]


@dataclass(frozen=True)
class TourEstimate:
    """How long a tour takes: metres driven, seconds driving, dwelling and in all (home to home)."""

    distance_m: float
    driving_s: float
    dwell_s: float
    total_s: float

    def to_json(self) -> dict[str, float]:
        """JSON-safe form."""
        return {"distance_m": round(self.distance_m, 2), "driving_s": round(self.driving_s, 1),
                "dwell_s": round(self.dwell_s, 1), "total_s": round(self.total_s, 1)}


def route_points(tour: Tour, home: Pose2D,
                 path_points: Callable[[int], Sequence[tuple[float, float]]] | None = None
                 ) -> list[tuple[float, float]]:
    """The straight-leg route of ``tour`` in ``map`` (metres): home, every stop (after the
    waypoints of its route path), home."""
    points: list[tuple[float, float]] = [(home.x, home.y)]
    for stop in tour.stops:
        if stop.route_path_id is not None and path_points is not None:
            points.extend(path_points(stop.route_path_id))
        points.append((stop.x_m, stop.y_m))
    points.append((home.x, home.y))
    return points


def estimate(tour: Tour, home: Pose2D, cfg: ToursConfig,
             path_points: Callable[[int], Sequence[tuple[float, float]]] | None = None
             ) -> TourEstimate:
    """Estimate ``tour`` from ``home`` through every stop (and its route path) back home."""
    points = route_points(tour, home, path_points)
    straight = sum(math.dist(a, b) for a, b in itertools.pairwise(points))
    distance = straight * cfg.estimate_detour_factor
    driving = distance / cfg.estimate_speed_mps
    dwell = sum(s.dwell_s for s in tour.stops)
    return TourEstimate(distance, driving, dwell, driving + dwell)


class TourService:
    """Tours, schedules and tour commands for the dashboard, the kiosk and the scheduler.

    Args:
        tours: the tour store.
        schedules: the schedule store.
        bus, clock: the application's.
        cfg: ``[tours]``.
        home: where tours start and end (``robot.home``), for estimates.
        path_points: a path of the path manager as points (for estimates), or None.
        enabled: whether the tree runs tours (``bt.tree = "tour"``); else starting is refused
            with the reason.
    """

    def __init__(self, tours: TourStore, schedules: ScheduleStore, bus: Bus, clock: Clock,
                 cfg: ToursConfig, home: Pose2D,
                 path_points: Callable[[int], Sequence[tuple[float, float]]] | None = None,
                 enabled: bool = True) -> None:
        self.tours = tours
        self.schedules = schedules
        self.bus = bus
        self.clock = clock
        self.cfg = cfg
        self.home = home
        self.path_points = path_points
        self.enabled = enabled
        self._requests = itertools.count(1)
        tours.add_listener(lambda change, tid, actor: self._event(
            "tours.changed", change=change, tour_id=tid, actor=actor))
        schedules.add_listener(lambda change, sid, actor: self._event(
            "schedules.changed", change=change, schedule_id=sid, actor=actor))

    def _event(self, kind: str, **detail: Any) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, detail))

    # --- tours ------------------------------------------------------------------------------

    def estimate(self, tour_id: int) -> TourEstimate:
        """The estimated duration of tour ``tour_id`` (home to home)."""
        return estimate(self.tours.get(tour_id), self.home, self.cfg, self.path_points)

    def duration_s(self, tour_id: int) -> float:
        """Estimated seconds of tour ``tour_id`` (0 when it does not exist)."""
        try:
            return self.estimate(tour_id).total_s
        except TourError:
            return 0.0

    def describe(self, tour: Tour) -> dict[str, Any]:
        """A tour as the dashboard shows it: data, problems, estimate, schedules, running."""
        running = self.running()
        return {**tour.to_json(), "problems": self.tours.problems(tour),
                "estimate": self.estimate(tour.id).to_json(),
                "route": [[round(x, 3), round(y, 3)]
                          for x, y in route_points(tour, self.home, self.path_points)],
                "schedule_ids": [s.id for s in self.schedules.for_tour(tour.id)],
                "running": running is not None and running.tour_id == tour.id}

    def list_tours(self) -> list[dict[str, Any]]:
        """Every tour, described."""
        return [self.describe(t) for t in self.tours.list_tours()]

    def create_tour(self, name: Any, stops: Sequence[Any] = (), *, kiosk: bool = True,
                    actor: str = "") -> Tour:
        """Create a tour from a name and stops in their JSON form."""
        return self.tours.create(name, [stop_from_json(s) for s in stops], kiosk=kiosk,
                                 actor=actor)

    def add_stop(self, tour_id: Any, stop: Any, index: int | None = None, *,
                 expect_revision: int | None = None, actor: str = "") -> Tour:
        """Insert a stop given in its JSON form (``{"name", "x_m", "y_m", ...}``)."""
        return self.tours.add_stop(tour_id, stop_from_json(stop), index,
                                   expect_revision=expect_revision, actor=actor)

    def running(self) -> TourState | None:
        """The running tour (from ``/tour``), or None."""
        state = self.bus.latest(TOUR)
        return state if state is not None and state.tour_id is not None else None

    def delete_tour(self, tour_id: Any, *, force: bool = False, actor: str = "") -> str:
        """Delete a tour (see the module docstring for running and scheduled tours); return a
        sentence saying what was done."""
        tour = self.tours.get(tour_id)
        running = self.running()
        is_running = running is not None and running.tour_id == tour.id
        scheduled = self.schedules.for_tour(tour.id)
        if not force and (is_running or scheduled):
            why = []
            if is_running:
                why.append("it is running now (stop it first)")
            if scheduled:
                ids = ", ".join(str(s.id) for s in scheduled)
                why.append(f"schedule{'s' if len(scheduled) > 1 else ''} {ids} run"
                           f"{'' if len(scheduled) > 1 else 's'} it (delete "
                           f"{'them' if len(scheduled) > 1 else 'it'} first)")
            raise TourError(f"Tour {tour.id} ({tour.name}) was not deleted: "
                            f"{' and '.join(why)}; or delete it with force to do both.")
        done = []
        if is_running:
            self.stop_tour(source="tours", actor=actor)
            done.append("stopped")
        removed = self.schedules.delete_for_tour(tour.id, actor=actor) if scheduled else []
        self.tours.delete(tour.id, actor=actor)
        done.append("deleted")
        extra = f"; schedule{'s' if len(removed) > 1 else ''} " \
                f"{', '.join(map(str, removed))} removed" if removed else ""
        return f"Tour {tour.id} ({tour.name}) {' and '.join(done)}{extra}."

    def start_problem(self, tour_id: int | None) -> str | None:
        """Why tour ``tour_id`` (None: the first) cannot be started now, or None."""
        if not self.enabled:
            return "Tours need the tour guide tree (bt.tree = 'tour')."
        tour = self.tours.first() if tour_id is None else self.tours.get(tour_id)
        if tour is None:
            return "There are no tours yet; create one first."
        problems = self.tours.problems(tour)
        return " ".join(problems) if problems else None

    def start_tour(self, tour_id: int | None = None, *, source: str = "web",
                   request_id: str = "", actor: str = "") -> str:
        """Ask the tree to run tour ``tour_id`` (None: the first); return the request id that
        the tree's answer (``bt.command_accepted``/``rejected``) carries."""
        problem = self.start_problem(tour_id)
        if problem:
            raise TourError(problem)
        tour = self.tours.first() if tour_id is None else self.tours.get(tour_id)
        assert tour is not None
        rid = request_id or f"{source}-tour-{next(self._requests)}"
        self.bus.publish(OPERATOR, OperatorCommand(self.clock.now(), "start_tour",
                                                   source=_who(source, actor), request_id=rid,
                                                   tour_id=tour.id))
        return rid

    def stop_tour(self, *, source: str = "web", actor: str = "") -> str:
        """Ask the tree to stop the running tour; return the request id."""
        if self.running() is None:
            raise TourError("No tour is running.")
        rid = f"{source}-stop-{next(self._requests)}"
        self.bus.publish(OPERATOR, OperatorCommand(self.clock.now(), "stop_tour",
                                                   source=_who(source, actor), request_id=rid))
        return rid

    # --- schedules --------------------------------------------------------------------------

    def add_schedule(self, tour_id: Any, days: Any, times: Any, *, enabled: bool = True,
                     note: str = "", actor: str = "") -> Schedule:
        """Schedule a tour (refused when it overlaps another scheduled tour)."""
        return self.schedules.add(tour_id, days, times, enabled=enabled, note=note,
                                  actor=actor)

    def upcoming(self, count: int = 10, days: int = 7) -> list[dict[str, Any]]:
        """The next ``count`` scheduled starts within ``days`` (local time, tour names)."""
        now = self.clock.wall_time()
        occs: list[Occurrence] = self.schedules.occurrences(now, now + days * 86400.0)[:count]
        return [{**o.to_json(), "tour": self._name(o.tour_id)} for o in occs]

    def _name(self, tour_id: int) -> str:
        try:
            return self.tours.get(tour_id).name
        except TourError:
            return ""

    def tour_name(self, tour_id: int) -> str:
        """The name of ``tour_id`` ("" when it no longer exists)."""
        return self._name(tour_id)


def _who(source: str, actor: str) -> str:
    return f"{source}:{actor}" if actor else source
