"""The tour guide tree's hook into the tour store: which tour ``start_tour`` runs, and what the
visitors hear and see while it runs.

:class:`Tours2BB` is a data feed (SUCCESS every tick, never RUNNING) placed *before* the
operator feed in the tour tree's root, so it sees each ``start_tour`` first and sets
``ctx.tour_route`` to the tour the command names (``tour_id``; None = the first tour of the
store), which the operator feed and Change Path then use unchanged. A tour that does not exist
(or has no stops) leaves no tour route, so the tree refuses the command; the tour service checks
this beforehand with a precise reason. The route is a :class:`TourRoute`: the follower's route
for the tour (id −1), with each stop's route path expanded into pass-through waypoints and the
tour's id, its starter and the voice of each stop.

Each tick it also watches the follower (one tick behind it) and:

* publishes ``tour.started``, ``tour.finished`` and ``tour.stopped`` (with the tour's id, name,
  who started it and the stops reached);
* sends the rover home (``go_home`` on ``/operator``, source ``tour``) when a tour has finished
  and ``tours.return_home`` is on;
* says where the rover goes when it leaves a stop (``tours.announce_next_stop``), and speaks
  each stop's message in its language/voice;
* publishes the running tour on ``/tour`` (:class:`~curio.core.messages.TourState`) for the
  kiosk and the scheduler, when its stop or phase changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import py_trees
from py_trees.common import Status

from curio.core.config import ToursConfig
from curio.core.messages import Event, OperatorCommand, TourState
from curio.core.topics import EVENTS, OPERATOR, POSE, TOUR
from curio.tours.model import Tour
from curio.tours.store import TourStore

from .follower import TOUR_ROUTE_ID, Route, Stop
from .paths import PathError, PathManager

if TYPE_CHECKING:
    from .context import TreeContext
    from .speech import Speaker

__all__ = ["TourRoute", "Tours2BB", "tour_route"]

ACTIVE_PHASES = ("moving", "dwelling", "held", "failed", "interrupted")


@dataclass(frozen=True, slots=True)
class TourRoute(Route):
    """The follower's route for a tour of the store.

    Attributes:
        tour_id: the tour.
        source, request_id: who asked for it, and the request's id.
        stop_of: for each route waypoint, the index of its tour stop (None: a waypoint of a
            route path on the way to the next stop).
        voices: for each route waypoint, its message's ``(language, voice)``.
    """

    tour_id: int = 0
    source: str = ""
    request_id: str = ""
    stop_of: tuple[int | None, ...] = ()
    voices: tuple[tuple[str, str], ...] = ()

    def tour_stops(self) -> int:
        """How many tour stops (not route waypoints) it has."""
        return sum(1 for i in self.stop_of if i is not None)


def tour_route(tour: Tour, paths: PathManager | None, *, loop: bool = False, source: str = "",
               request_id: str = "") -> TourRoute:
    """``tour`` as a follower route: each stop's route path (if any) then the stop itself."""
    stops: list[Stop] = []
    stop_of: list[int | None] = []
    voices: list[tuple[str, str]] = []
    for i, stop in enumerate(tour.stops):
        if stop.route_path_id is not None and paths is not None:
            try:
                waypoints = paths.get(stop.route_path_id).waypoints
            except PathError:  # deleted since: drive straight to the stop
                waypoints = []
            for w in waypoints:
                stops.append(Stop(w.x_m, w.y_m, w.yaw_rad))
                stop_of.append(None)
                voices.append(("", ""))
        stops.append(Stop(stop.x_m, stop.y_m, stop.yaw_rad, name=stop.name,
                          dwell_s=stop.dwell_s, message=stop.message.text))
        stop_of.append(i)
        voices.append((stop.message.language, stop.message.voice))
    return TourRoute(TOUR_ROUTE_ID, tour.name, tuple(stops), loop=loop, skip_failed=True,
                     tour_id=tour.id, source=source, request_id=request_id,
                     stop_of=tuple(stop_of), voices=tuple(voices))


class Tours2BB(py_trees.behaviour.Behaviour):
    """The tour feed (see the module docstring).

    Args:
        ctx: the tree's context (its follower, bus, clock, sink and ``tour_route``).
        store: the tour store.
        cfg: ``[tours]``.
        speaker: speaks announcements and stop messages in their voice (None: silent).
    """

    def __init__(self, ctx: TreeContext, store: TourStore, cfg: ToursConfig,
                 speaker: Speaker | None = None, name: str = "Tours2BB") -> None:
        super().__init__(name)
        self.ctx = ctx
        self.store = store
        self.cfg = cfg
        self.speaker = speaker
        self.sub = ctx.bus.subscribe(OPERATOR)
        self.current: TourRoute | None = None
        self.started_at_s = 0.0
        self._seen: tuple[int, str] | None = None
        self._dwell_from_s = 0.0
        self._state_key: tuple[Any, ...] | None = None
        if speaker is not None:
            ctx.follower.speak = self.speak_stop

    def close(self) -> None:
        """Stop receiving commands."""
        self.sub.close()

    def update(self) -> Status:
        """Resolve tour commands, then watch the running tour."""
        for cmd in self.sub.drain():
            if cmd.action == "start_tour":
                self.ctx.tour_route = self._resolve(cmd)
        self._watch()
        return Status.SUCCESS

    def _resolve(self, cmd: OperatorCommand) -> TourRoute | None:
        tour = self.store.first() if cmd.tour_id is None else \
            next((t for t in self.store.list_tours() if t.id == cmd.tour_id), None)
        if tour is None or not tour.stops:
            return None
        return tour_route(tour, self.ctx.paths, loop=self.ctx.cfg.tour_loop,
                          source=cmd.source, request_id=cmd.request_id)

    # --- watching the follower --------------------------------------------------------------

    def _event(self, kind: str, route: TourRoute, **detail: Any) -> None:
        self.ctx.bus.publish(EVENTS, Event(self.ctx.clock.now(), kind, {
            "tour_id": route.tour_id, "tour": route.name, "source": route.source,
            "request_id": route.request_id, **detail}))

    def _watch(self) -> None:
        f = self.ctx.follower
        route = f.route if isinstance(f.route, TourRoute) and f.phase in ACTIVE_PHASES else None
        current = self.current
        if current is not None and route is not current:
            self._ended(current, finished=f.route is current and f.phase == "finished")
        if route is not None and route is not current:
            self.current = route
            self.started_at_s = self.ctx.clock.now()
            self._seen = None
            self._event("tour.started", route, stops=route.tour_stops())
        if self.current is not None:
            self._progress(self.current)
        self._publish_state()

    def _ended(self, route: TourRoute, *, finished: bool) -> None:
        f = self.ctx.follower
        states = f.states if f.route is route else []
        reached = sum(1 for i, s in enumerate(states)
                      if s == "reached" and i < len(route.stop_of) and route.stop_of[i] is not None)
        duration = round(self.ctx.clock.now() - self.started_at_s, 1)
        if finished:
            self._event("tour.finished", route, stops_reached=reached,
                        stops=route.tour_stops(), duration_s=duration)
            if self.cfg.return_home:
                self.ctx.bus.publish(OPERATOR, OperatorCommand(
                    self.ctx.clock.now(), "go_home", source="tour",
                    request_id=f"tour-{route.tour_id}-home"))
        else:
            if f.route is route:
                reason = self.ctx.sink.text or "stopped"
            else:
                reason = f"replaced by {f.route.name}" if f.route is not None else "stopped"
            self._event("tour.stopped", route, stops_reached=reached, stops=route.tour_stops(),
                        duration_s=duration, reason=reason)
        self.current = None

    def _progress(self, route: TourRoute) -> None:
        """Announce the next stop when the rover sets off for it."""
        f = self.ctx.follower
        key = (f.index, f.phase)
        if key == self._seen:
            return
        previous, self._seen = self._seen, key
        if f.phase == "dwelling":
            self._dwell_from_s = self.ctx.clock.now()
        left_stop = previous is None or (
            previous[0] != f.index and 0 <= previous[0] < len(route.stop_of)
            and route.stop_of[previous[0]] is not None)
        if f.phase != "moving" or not left_stop:
            return
        nxt = self._next_stop(route, f.index)
        if nxt is None or self.speaker is None or not self.cfg.announce_next_stop:
            return
        name = route.stops[nxt].name
        text = (f"Welcome to the tour {route.name}. Our first stop is {name}. Please follow me."
                if self._reached_none(route) else f"Next stop: {name}. Please follow me.")
        self.speaker.say(text, *route.voices[nxt])

    @staticmethod
    def _next_stop(route: TourRoute, index: int) -> int | None:
        for i in range(index, len(route.stop_of)):
            if route.stop_of[i] is not None:
                return i
        return None

    def _reached_none(self, route: TourRoute) -> bool:
        f = self.ctx.follower
        return not any(s == "reached" for i, s in enumerate(f.states)
                       if i < len(route.stop_of) and route.stop_of[i] is not None)

    def speak_stop(self, text: str) -> None:
        """The follower's speech callback: a stop's message in its language and voice."""
        if self.speaker is None:
            return
        f = self.ctx.follower
        route = f.route
        if isinstance(route, TourRoute) and 0 <= f.index < len(route.voices):
            self.speaker.say(text, *route.voices[f.index])
        else:
            self.speaker.say(text)

    # --- /tour ------------------------------------------------------------------------------

    def _publish_state(self) -> None:
        f = self.ctx.follower
        route = self.current
        if route is None:
            key: tuple[Any, ...] = (None,)
            state = TourState(self.ctx.clock.now())
        else:
            i = self._next_stop(route, f.index) if f.phase == "moving" else f.index
            i = f.index if i is None else i
            stop = route.stops[i] if 0 <= i < len(route.stops) else None
            after = self._next_stop(route, i + 1)
            phase = "dwelling" if f.phase == "dwelling" else \
                "moving" if f.phase == "moving" else "failed" if f.phase in (
                    "failed", "interrupted") else "held"
            key = (route, i, phase)
            stop_no = route.stop_of[i] if 0 <= i < len(route.stop_of) else None
            state = TourState(
                self.ctx.clock.now(), tour_id=route.tour_id, name=route.name,
                source=route.source, phase=phase, stop_index=stop_no,
                stop_name=stop.name if stop else "", message=stop.message if stop else "",
                next_stop_name=route.stops[after].name if after is not None else "",
                stops_total=route.tour_stops(), eta_s=self._eta(stop, phase))
        if key != self._state_key:
            self._state_key = key
            self.ctx.bus.publish(TOUR, state)

    def _eta(self, stop: Stop | None, phase: str) -> float | None:
        if stop is None:
            return None
        if phase == "dwelling":
            return round(max(0.0, self._dwell_from_s + stop.dwell_s - self.ctx.clock.now()), 1)
        pose = self.ctx.bus.latest(POSE)
        if phase != "moving" or pose is None:
            return None
        distance = math.hypot(stop.x_m - pose.pose.x, stop.y_m - pose.pose.y)
        return round(distance * self.cfg.estimate_detour_factor / self.cfg.estimate_speed_mps, 1)
