"""The tour tree runs named tours of the tour store: selection by id, route paths, events,
voices, the way home, /tour for the kiosk, and the service's rules (delete while running)."""

from __future__ import annotations

from typing import Any

import pytest

from curio.bt.paths import PathManager
from curio.bt.runner import build_tree_runner
from curio.bt.speech import Speaker
from curio.core.config import BtConfig, PathConfig, ToursConfig
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorCommand, TourState
from curio.core.topics import EVENTS, OPERATOR, PROGRESS, STATUS, TOUR, make_bus
from curio.speech.engines import Utterance
from curio.tours.model import TourError, make_message, make_stop
from curio.tours.schedule import ScheduleStore
from curio.tours.service import TourService
from curio.tours.store import TourStore

from .bt_fakes import FakeNavigator, Harness, ManualClock


class RecordingEngine:
    """A speech engine that remembers what it was asked to say, instantly."""

    def __init__(self) -> None:
        self.said: list[Utterance] = []

    @property
    def available(self) -> bool:
        return True

    async def speak(self, utterance: Utterance) -> None:
        self.said.append(utterance)

    async def stop(self) -> None:
        pass


def tours_store() -> TourStore:
    s = TourStore(None)
    s.create("Highlights", [
        make_stop("Lobby", 1.0, 0.0, dwell_s=1.0, message=make_message("Welcome!", "en")),
        make_stop("Gallery", 5.0, 1.0, dwell_s=1.0,
                  message=make_message("La galerie.", "fr", "fr+f2"), route_path_id=1),
    ])
    s.create("Short", [make_stop("Desk", 2.0, 2.0, dwell_s=0.0)])
    s.create("Empty")
    return s


def harness(tours: TourStore, speaker: Speaker | None = None,
            **tours_kw: Any) -> tuple[Harness, Speaker]:
    paths = [PathConfig(name="Home", points=[(0.0, 0.0)]),
             PathConfig(name="Via", points=[(3.0, 0.0), (4.0, 0.5)])]
    cfg = BtConfig(speak=False, tree="tour", paths=paths)
    bus = make_bus()
    clock = ManualClock()
    nav = FakeNavigator()
    pm = PathManager(cfg.paths, None)
    speaker = speaker or Speaker(enabled=False)
    subs = bus.subscribe(STATUS), bus.subscribe(EVENTS), bus.subscribe(PROGRESS)
    runner = build_tree_runner(cfg, bus, clock, nav, pm, speaker, tours=tours,
                               tours_cfg=ToursConfig(**tours_kw))
    return Harness(runner, nav, clock, bus, pm, *subs, speaker), speaker  # type: ignore[arg-type]


def drive_to_end(h: Harness, goals: int) -> None:
    for _ in range(goals):
        h.nav.succeed()
        h.tick(4)


def test_start_tour_runs_the_named_tour_with_its_route_path() -> None:
    h, _ = harness(tours_store())
    h.press("start_tour", tour_id=1, request_id="k1")
    h.tick(2)
    assert h.nav.target() == (1.0, 0.0)
    started = h.of("tour.started")[0].detail
    assert started == {"tour_id": 1, "tour": "Highlights", "source": "test",
                       "request_id": "k1", "stops": 2}
    h.nav.succeed()
    h.tick(4)  # dwell 1 s, then the route path's waypoints before the gallery
    assert h.nav.target() == (3.0, 0.0)
    h.nav.succeed()
    h.tick()
    assert h.nav.target() == (4.0, 0.5)
    h.nav.succeed()
    h.tick()
    assert h.nav.target() == (5.0, 1.0)
    assert [e.detail["name"] for e in h.of("tour.stop")] == ["Lobby"]
    h.nav.succeed()
    h.tick(4)
    finished = h.of("tour.finished")[0].detail
    assert finished["stops_reached"] == 2 and finished["stops"] == 2
    h.tick(2)
    assert h.nav.target() == (0.0, 0.0) and h.status.text == "Going home"  # return_home
    home = [e for e in h.of("bt.command_accepted") if e.detail["action"] == "go_home"]
    assert home and home[0].detail["source"] == "tour"


def test_another_tour_by_id_and_the_first_tour_by_default() -> None:
    h, _ = harness(tours_store())
    h.press("start_tour", tour_id=2)
    h.tick(2)
    assert h.nav.target() == (2.0, 2.0)
    assert h.of("tour.started")[0].detail["tour"] == "Short"
    h.press("stop_tour")
    h.tick(2)
    stopped = h.of("tour.stopped")[0].detail
    assert stopped["tour"] == "Short" and stopped["reason"] == "Tour stopped"
    assert not [e for e in h.of("bt.command_accepted") if e.detail["action"] == "go_home"]
    h.press("start_tour")  # no id: the first tour of the list
    h.tick(2)
    assert h.nav.target() == (1.0, 0.0)


@pytest.mark.parametrize("tour_id", [3, 99])
def test_an_empty_or_unknown_tour_is_refused_by_the_tree(tour_id: int) -> None:
    h, _ = harness(tours_store())
    h.press("start_tour", tour_id=tour_id)
    h.tick()
    assert "No tour stops" in h.last_message("bt.command_rejected")
    assert not h.nav.goals


def test_tour_state_for_the_kiosk() -> None:
    h, _ = harness(tours_store())
    sub = h.bus.subscribe(TOUR)
    h.bus.publish(OPERATOR, OperatorCommand(0.0, "start_tour", tour_id=1, source="kiosk"))
    h.tick(2)
    h.nav.succeed()
    h.tick(2)
    states: list[TourState] = sub.drain()
    moving = next(s for s in states if s.phase == "moving")
    assert (moving.name, moving.stop_name, moving.next_stop_name, moving.stops_total,
            moving.source) == ("Highlights", "Lobby", "Gallery", 2, "kiosk")
    dwelling = states[-1]
    assert dwelling.phase == "dwelling" and dwelling.message == "Welcome!"
    assert dwelling.eta_s is not None and dwelling.eta_s <= 1.0
    h.tick(2)
    leg = sub.drain()[-1]
    assert leg.phase == "moving" and leg.stop_name == "Gallery" and leg.stop_index == 1
    h.press("stop_tour")
    h.tick(2)
    last = sub.drain()[-1]
    assert last.tour_id is None and last.phase == "idle"


async def test_messages_in_their_voice_and_the_next_stop_announced() -> None:
    engine = RecordingEngine()
    speaker = Speaker(engine=engine)
    speaker.queue.max_waiting = 8
    h, _ = harness(tours_store(), speaker)
    h.press("start_tour", tour_id=1)
    h.tick(2)
    h.nav.succeed()
    h.tick(4)
    for _ in range(3):
        h.nav.succeed()
        h.tick()
    await speaker.queue.idle()
    said = [(u.text, u.language, u.voice) for u in engine.said]
    assert said[0] == ("Welcome to the tour Highlights. Our first stop is Lobby. Please follow "
                       "me.", "en", "")
    assert said[1] == ("Welcome!", "en", "")
    assert said[2] == ("Next stop: Gallery. Please follow me.", "fr", "fr+f2")
    assert said[3] == ("La galerie.", "fr", "fr+f2")
    assert len(said) == 4  # the route path's waypoints are not announced
    await speaker.close()


def test_no_way_home_when_switched_off() -> None:
    h, _ = harness(tours_store(), return_home=False)
    h.press("start_tour", tour_id=2)
    h.tick(2)
    drive_to_end(h, 1)
    assert h.of("tour.finished") and h.bb("phase") == "finished"
    assert not [e for e in h.of("bt.command_accepted") if e.detail["action"] == "go_home"]


def service(tours: TourStore, bus: Any, clock: Any) -> TourService:
    schedules = ScheduleStore(None, __import__("zoneinfo").ZoneInfo("UTC"), lambda _t: 600.0,
                              tours.schedule_problem)
    return TourService(tours, schedules, bus, clock, ToursConfig(), Pose2D())


def test_deleting_a_running_tour_is_refused_unless_forced_which_stops_it() -> None:
    tours = tours_store()
    h, _ = harness(tours)
    svc = service(tours, h.bus, h.clock)
    rid = svc.start_tour(1, source="kiosk")
    h.tick(2)
    assert h.of("tour.started")[0].detail["request_id"] == rid
    assert svc.running() is not None and svc.running().tour_id == 1  # type: ignore[union-attr]
    with pytest.raises(TourError, match=r"Tour 1 \(Highlights\) was not deleted: it is running "
                                        r"now \(stop it first\)"):
        svc.delete_tour(1)
    svc.add_schedule(2, "daily", ["10:00"])
    with pytest.raises(TourError, match=r"schedule 1 runs it \(delete it first\)"):
        svc.delete_tour(2)
    assert svc.delete_tour(1, force=True) == "Tour 1 (Highlights) stopped and deleted."
    h.tick(2)
    assert h.nav.active is None and h.of("tour.stopped")
    assert [t.id for t in tours.list_tours()] == [2, 3]
    assert "schedule 1 removed" in svc.delete_tour(2, force=True)
    assert svc.schedules.list_schedules() == []
    h.collect()
    changes = [e.detail["change"] for e in h.of("tours.changed")]
    assert changes == ["deleted", "deleted"]


def test_the_service_refuses_to_start_what_cannot_run() -> None:
    tours = tours_store()
    h, _ = harness(tours)
    svc = service(tours, h.bus, h.clock)
    with pytest.raises(TourError, match=r"Tour 3 \(Empty\) has no stops"):
        svc.start_tour(3)
    with pytest.raises(TourError, match="There is no tour 9"):
        svc.start_tour(9)
    tours.check_place = lambda x, y: "is inside an obstacle on the map" if x > 4 else None
    with pytest.raises(TourError, match=r"Stop 2 \(Gallery\) is inside an obstacle"):
        svc.start_tour(1)
    with pytest.raises(TourError, match="No tour is running"):
        svc.stop_tour()
    svc.enabled = False
    with pytest.raises(TourError, match=r"bt\.tree = 'tour'"):
        svc.start_tour(2)
    assert not h.nav.goals


def test_editing_a_running_tour_applies_from_the_next_run() -> None:
    tours = tours_store()
    h, _ = harness(tours)
    h.press("start_tour", tour_id=2)
    h.tick(2)
    tours.update_stop(2, 0, x_m=2.5)
    h.nav.succeed()
    h.tick(4)
    assert [e.detail["x_m"] for e in h.of("tour.stop")] == [2.0]
    h.press("start_tour", tour_id=2)
    h.tick(2)
    assert h.nav.target() == (2.5, 2.0)

