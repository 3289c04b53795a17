"""The soak's building: its tours, their schedule, when nothing happens, and the hooks other
features plug into.

The default building (``maps/curio_building.yaml``) with the two tours of ``curio sim
tour-day`` (Highlights: lobby, gallery; North wing: library, meeting room), scheduled every
``TOUR_EVERY_MIN`` minutes from ``OPEN`` to ``LAST_TOUR`` every day, the two alternating, in
``Europe/London``. The soak starts at ``START`` local time. The first rover authors the tours
and the schedule through the tour service (so they are persisted like an operator's); every
later rover finds them on disk.

**Time-lapse.** While the rover is parked (idle, no tour running or waiting to start, no help
open, not moving) and no fault is being judged, the building's clock jumps
(``SimClock.jump_wall``) to just before the next thing that happens: ``LEAD_S`` before a
scheduled tour (the scheduler must see it come), ``SOON_LEAD_S`` before the next fault of the
campaign or the soak's end. Nothing that moves is skipped; the report says how much was
jumped. The control stack never reads the building's clock (schedules and logs do).

**Hooks** (:class:`SoakHooks`): the battery over a time-lapse (:meth:`SoakHooks.on_lapse`: the
dock's charger charges a docked rover; the soak runs with ``dock.enabled``, so after every
tour the rover docks at home and backs out for the next) and visitors walking
(:meth:`SoakHooks.on_start` may add them to the world).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from zoneinfo import ZoneInfo

from curio.core.topics import STATUS, TOUR
from curio.tours.scheduler import READY_STATES

__all__ = ["DAY_TOURS", "LEAD_S", "Building", "SoakHooks", "schedule_times"]

TIMEZONE = "Europe/London"
START = dt.datetime(2025, 6, 2, 7, 50)  # a Monday, local time
OPEN = dt.time(8, 0)
LAST_TOUR = dt.time(19, 30)
TOUR_EVERY_MIN = 30
LEAD_S = 30.0
SOON_LEAD_S = 1.0
MOVING_MPS = 0.01
CHARGE_V_PER_H = 2.0
HOME_M = 0.5

DAY_TOURS: list[tuple[str, list[dict[str, Any]]]] = [
    ("Highlights", [
        {"name": "Lobby", "x_m": 2.0, "y_m": -2.5, "dwell_s": 10.0,
         "message": "Welcome to the Curio building! I am Curio, your guide today."},
        {"name": "Gallery", "x_m": 12.5, "y_m": 1.5, "dwell_s": 10.0,
         "message": "This is the gallery: the plinths show the rover's history."},
    ]),
    ("North wing", [
        {"name": "Library", "x_m": 1.0, "y_m": 11.8, "dwell_s": 10.0,
         "message": {"text": "Bienvenue à la bibliothèque.", "language": "fr"}},
        {"name": "Meeting room", "x_m": 19.5, "y_m": 12.0, "dwell_s": 10.0,
         "message": "The meeting room: teams plan their missions here."},
    ]),
]


def schedule_times() -> list[list[str]]:
    """Each tour's daily start times (``HH:MM``): every ``TOUR_EVERY_MIN`` minutes from
    ``OPEN`` to ``LAST_TOUR``, the tours taking turns."""
    out: list[list[str]] = [[] for _ in DAY_TOURS]
    minute, k = OPEN.hour * 60 + OPEN.minute, 0
    last = LAST_TOUR.hour * 60 + LAST_TOUR.minute
    while minute <= last:
        out[k % len(DAY_TOURS)].append(f"{minute // 60:02d}:{minute % 60:02d}")
        minute += TOUR_EVERY_MIN
        k += 1
    return out


def start_wall_s(at: dt.time | None = None) -> float:
    """The UNIX time the soak starts at: ``START`` in ``TIMEZONE``, or that day at local time
    ``at`` (``curio soak --start HH:MM``)."""
    start = START if at is None else dt.datetime.combine(START.date(), at)
    return start.replace(tzinfo=ZoneInfo(TIMEZONE)).timestamp()


class SoakHooks:
    """What other features plug into the soak (the defaults stand in for them).

    * :meth:`on_start` — once the rover runs (``people``: add visitors walking in the world);
    * :meth:`on_lapse` — the building's clock jumped ``jumped_s`` while the rover was parked
      (the dock's charger charges a docked rover; without a dock, the battery charges at
      ``CHARGE_V_PER_H`` when the rover is within ``HOME_M`` of home, as a charger would).
    """

    def on_start(self, app: Any) -> None:
        """The rover runs (nothing by default)."""

    def on_lapse(self, app: Any, jumped_s: float) -> None:
        """With a dock (``dock.enabled``, the soak's default): the simulated charger charges a
        docked rover over the lapse. Without one, charge the battery while parked within
        ``HOME_M`` of home, as a charger there would."""
        world = app.world
        if world is None:
            return
        if world.dock is not None:
            world.lapse(jumped_s)
            return
        if world.truth_pose.distance_to(app.robot.home) > HOME_M:
            return
        volts = world.battery_voltage()
        full = 8.1
        world.set_battery_voltage(min(full, volts + CHARGE_V_PER_H * jumped_s / 3600.0))


@dataclass
class Building:
    """The building day around one rover (see the module docstring).

    Args:
        app: the running application (its tour service, bus, world).
        hooks: the features' hooks.
    """

    app: Any
    hooks: SoakHooks

    def author(self) -> bool:
        """Create the tours and their schedule unless the rover already has them; True when
        they were created (the first rover)."""
        service = self.app.tours.service
        if service.list_tours():
            return False
        days = ["daily"]
        for (name, stops), times in zip(DAY_TOURS, schedule_times(), strict=True):
            tour = service.create_tour(name, stops, actor="soak")
            service.add_schedule(tour.id, days, times, actor="soak", note="soak")
        return True

    def parked(self, busy: bool) -> bool:
        """Idle and still: no tour, nothing scheduled waiting, no help open, not moving, and no
        fault being judged (``busy``)."""
        if busy:
            return False
        bus = self.app.bus
        status = bus.latest(STATUS)
        tour = bus.latest(TOUR)
        if status is None or status.state not in READY_STATES:
            return False
        if tour is not None and tour.tour_id is not None:
            return False
        if self.app.tours.scheduler.pending:
            return False
        v, w = self.app.world.truth_twist
        return bool(abs(v) < MOVING_MPS and abs(w) < MOVING_MPS)

    def next_scheduled(self, now_wall_s: float) -> float | None:
        """The building time of the next scheduled start not yet seen by the scheduler."""
        scheduler = self.app.tours.scheduler
        seen = scheduler.last_check_wall_s
        after = min(now_wall_s, seen) if seen is not None else now_wall_s
        nxt = self.app.tours.schedules.next_occurrence(after)
        return None if nxt is None else float(nxt.wall_s)

    def lapse(self, clock: Any, now_wall_s: float, nexts: list[float],
              on_jump: Callable[[float], None]) -> float:
        """Jump the building's clock to ``SOON_LEAD_S`` before the earliest of ``nexts`` (the
        next fault, the end) or ``LEAD_S`` before the next scheduled tour, when that is more
        than 5 s away; return the jump (seconds)."""
        times = [t - SOON_LEAD_S for t in nexts if math.isfinite(t)]
        scheduled = self.next_scheduled(now_wall_s)
        if scheduled is not None:
            times.append(scheduled - LEAD_S)
        if not times:
            return 0.0
        gap = min(times) - now_wall_s
        if gap <= 5.0:
            return 0.0
        clock.jump_wall(gap)
        self.hooks.on_lapse(self.app, gap)
        on_jump(gap)
        return gap
