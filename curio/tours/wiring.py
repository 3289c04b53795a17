"""Tours wiring: the tour and schedule stores, the service and the scheduler part.

Built before the behaviour tree (the tour tree reads the tour store) and after estimation (a
stop is checked against the navigation map). The path manager is passed in (as the small
:class:`PathLookup` interface: tours sit below the behaviour tree and do not import it) so
tours can follow its paths between stops.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol
from zoneinfo import ZoneInfo

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.parts import Part, Parts
from curio.estimation.maps import OccupancyGrid
from curio.robot import RobotModel

from .journal import TourJournal
from .model import TourError
from .placement import MapPlacement
from .schedule import ScheduleStore
from .scheduler import Scheduler
from .service import TourService, estimate
from .store import TourStore

__all__ = ["PathLookup", "Tours", "build_tours"]


class _Point(Protocol):
    @property
    def x_m(self) -> float: ...

    @property
    def y_m(self) -> float: ...


class _Path(Protocol):
    @property
    def waypoints(self) -> Sequence[_Point]: ...


class PathLookup(Protocol):
    """What tours need of the path manager (``curio/bt/paths.py``): its ids and a path's
    waypoints (``get`` raises ``ValueError`` for an unknown id)."""

    def ids(self) -> list[int]:
        """The ids of every path."""
        ...

    def get(self, path_id: int) -> _Path:
        """Path ``path_id``."""
        ...


@dataclass(frozen=True)
class Tours:
    """The tours subsystem's objects."""

    store: TourStore
    schedules: ScheduleStore
    service: TourService
    scheduler: Scheduler
    placement: MapPlacement
    timezone: ZoneInfo


def build_tours(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
                grid: Callable[[], OccupancyGrid], paths: PathLookup) -> Tours:
    """Construct the stores, the service and the scheduler; register the scheduler and the
    tour journal (:mod:`curio.tours.journal`: an interrupted tour is reported at start).

    Raises:
        DataFileError: ``tours.json`` or ``schedules.json`` cannot be used (left untouched).
    """
    tcfg = cfg.tours
    tz = ZoneInfo(tcfg.timezone)
    placement = MapPlacement(grid, robot.inscribed_radius_m)

    def path_exists(path_id: int) -> bool:
        return path_id in paths.ids()

    def path_points(path_id: int) -> list[tuple[float, float]]:
        try:
            return [(w.x_m, w.y_m) for w in paths.get(path_id).waypoints]
        except ValueError:  # PathError: deleted since
            return []

    store = TourStore(cfg.data_path(tcfg.file), cfg.bt.tour_stops, placement, path_exists)

    def duration_of(tour_id: int) -> float:
        try:
            return estimate(store.get(tour_id), robot.home, tcfg, path_points).total_s
        except TourError:
            return 0.0

    def label(tour_id: int) -> str:
        try:
            return f"tour “{store.get(tour_id).name}”"
        except TourError:
            return f"tour {tour_id}"

    schedules = ScheduleStore(cfg.data_path(tcfg.schedules_file), tz, duration_of,
                              store.schedule_problem, tcfg.schedule_gap_s, label)
    service = TourService(store, schedules, bus, clock, tcfg, robot.home, path_points,
                          enabled=cfg.bt.tree == "tour")

    def start(tour_id: int, source: str, request_id: str) -> str:
        return service.start_tour(tour_id, source=source, request_id=request_id)

    scheduler = Scheduler(schedules, start, service.tour_name, bus, clock, tcfg,
                          require_localised=cfg.localization.enabled)

    async def close() -> None:
        scheduler.close()

    parts.add(Part("tours.scheduler", run=scheduler.run, close=close))
    journal = TourJournal(cfg.data_path(tcfg.file).with_name("tours.running.json"), bus, clock)
    parts.add(Part("tours.journal", run=journal.run, close=journal.close))
    return Tours(store, schedules, service, scheduler, placement, tz)
