"""Schedules (weekdays, times, closed days, summer time, overlap) and the scheduler on a
simulated clock: a ready rover starts the tour on time; a busy one is delayed, then skipped with
the reason; a refusal, a missed start after a clock jump, a closed day."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import pytest

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import ToursConfig
from curio.core.messages import (
    BatteryState,
    Event,
    LocalizationStatus,
    OperatorCommand,
    StatusText,
    TourState,
)
from curio.core.topics import BATTERY, EVENTS, LOCALIZATION, OPERATOR, STATUS, TOUR, make_bus
from curio.tours.files import DataFileError
from curio.tours.model import TourError
from curio.tours.schedule import ScheduleStore
from curio.tours.scheduler import Scheduler, readiness

LONDON = ZoneInfo("Europe/London")
MONDAY = dt.date(2025, 6, 2)


def wall(day: dt.date, hhmm: str, tz: ZoneInfo = LONDON) -> float:
    h, m = map(int, hhmm.split(":"))
    return dt.datetime(day.year, day.month, day.day, h, m, tzinfo=tz).timestamp()


def store(path: Path | None = None, minutes: float = 40.0) -> ScheduleStore:
    def problem(tour_id: int) -> str | None:
        return None if tour_id in (1, 2) else f"There is no tour {tour_id}."

    return ScheduleStore(path, LONDON, lambda _t: minutes * 60.0, problem, gap_s=300.0)


def test_weekdays_times_closed_days_and_persistence(tmp_path: Path) -> None:
    s = store(tmp_path / "schedules.json")
    a = s.add(1, "weekdays", ["14:00", "10:00", "9:05"], note="school groups")
    assert a.days == ("mon", "tue", "wed", "thu", "fri") and a.times == ("09:05", "10:00",
                                                                        "14:00")
    b = s.add(2, ["Saturday", "sun"], ["11:00"])
    assert b.days == ("sat", "sun")
    week = s.occurrences(wall(MONDAY, "00:00"), wall(MONDAY + dt.timedelta(days=7), "00:00"))
    assert len(week) == 5 * 3 + 2
    assert week[0].label == "Mon 2025-06-02 09:05" and week[0].tour_id == 1
    s.set_closed(["2025-06-03"], "staff training")
    week = s.occurrences(wall(MONDAY, "00:00"), wall(MONDAY + dt.timedelta(days=7), "00:00"))
    assert len(week) == 4 * 3 + 2 and all(o.local.date() != dt.date(2025, 6, 3) for o in week)
    nxt = s.next_occurrence(wall(MONDAY, "10:00"))
    assert nxt is not None and nxt.local.strftime("%H:%M") == "14:00"
    again = store(tmp_path / "schedules.json")
    assert again.list_schedules() == s.list_schedules()
    assert [c.note for c in again.closed_days()] == ["staff training"]


def test_summer_time_is_the_building_clock() -> None:
    s = store()
    s.add(1, "daily", ["10:00"])
    before = s.occurrences(wall(dt.date(2025, 3, 29), "00:00"), wall(dt.date(2025, 3, 31),
                                                                     "00:00"))
    gap = before[1].wall_s - before[0].wall_s
    assert gap == 23 * 3600  # the clocks went forward on Sunday 30 March 2025
    assert [o.local.hour for o in before] == [10, 10]


@pytest.mark.parametrize(("days", "times", "why"), [
    ("someday", ["10:00"], "'someday' is not a weekday"),
    (["mon"], ["25:00"], "'25:00' is not a time of day; use HH:MM"),
    ([], ["10:00"], "days must be a list of weekdays"),
    (["mon"], [], "times must be a list of 1 to 48"),
])
def test_bad_days_and_times_name_the_value(days: Any, times: Any, why: str) -> None:
    with pytest.raises(TourError, match=why):
        store().add(1, days, times)


def test_a_tour_with_no_stops_or_unknown_cannot_be_scheduled() -> None:
    with pytest.raises(TourError, match="Cannot schedule it: There is no tour 7"):
        store().add(7, "daily", ["10:00"])


def test_overlapping_schedules_are_refused_with_the_times() -> None:
    s = store(minutes=40.0)
    s.add(1, "weekdays", ["10:00", "14:00"])
    with pytest.raises(TourError, match=(
            r"Overlapping schedules: on Monday the 10:30 tour 2 would start before the 10:00 "
            r"tour 1 \(schedule 1\) is over \(about 40 min including the way home, plus 5 min "
            r"between tours\); start it at 10:45 or later")):
        s.add(2, ["mon"], ["10:30"])
    with pytest.raises(TourError, match="on Monday the 14:00 tour 1 would start before"):
        s.add(2, ["mon"], ["13:30"])
    with pytest.raises(TourError, match="Overlapping schedules"):
        s.add(2, "weekdays", ["10:00"])  # the very same time
    with pytest.raises(TourError, match="this schedule"):
        s.add(2, "sat", ["10:00", "10:20"])  # within one schedule
    assert len(s.list_schedules()) == 1
    s.add(2, ["mon"], ["10:45"])
    s.add(2, ["sat"], ["10:30"])  # another day: no overlap
    s.update(1, enabled=False)
    s.add(2, ["tue"], ["10:10"])  # a disabled schedule does not count
    with pytest.raises(TourError, match="Overlapping"):
        s.update(1, enabled=True)


def test_a_corrupt_schedule_file_is_refused_and_kept(tmp_path: Path) -> None:
    path = tmp_path / "schedules.json"
    path.write_text(json.dumps({"version": 1, "schedules": [
        {"id": 1, "tour_id": 1, "days": ["mon"], "times": ["26:00"]}]}))
    with pytest.raises(DataFileError, match=r"schedules file .* cannot be used: '26:00' is not "
                                            r"a time of day"):
        store(path)
    assert "26:00" in path.read_text()


# --- the scheduler on a simulated clock ---------------------------------------------------


class FakeTree:
    """Answers start_tour like the tour tree: accepted (the tour runs for ``run_s``) or
    rejected with a message."""

    def __init__(self, bus: Bus, clock: SimClock, reject: str = "") -> None:
        self.bus, self.clock, self.reject = bus, clock, reject
        self.sub = bus.subscribe(OPERATOR)
        self.commands: list[OperatorCommand] = []

    def answer(self) -> None:
        for cmd in self.sub.drain():
            self.commands.append(cmd)
            kind = "bt.command_rejected" if self.reject else "bt.command_accepted"
            self.bus.publish(EVENTS, Event(self.clock.now(), kind, {
                "action": cmd.action, "request_id": cmd.request_id,
                "message": self.reject or "Tour started: 2 stops."}))


def ready(bus: Bus, *, state: str = "idle", text: str = "Idle", volts: float = 8.0,
          loc: str = "ok") -> None:
    bus.publish(STATUS, StatusText(0.0, text, state))
    bus.publish(BATTERY, BatteryState(0.0, volts))
    bus.publish(LOCALIZATION, LocalizationStatus(0.0, loc))  # type: ignore[arg-type]


def make(start: str, reject: str = "", window_s: float = 120.0, loop_s: float = 0.5,
         **kw: Any) -> tuple[Scheduler, FakeTree, Bus, SimClock, list[Event]]:
    clock = SimClock(epoch_wall_s=wall(MONDAY, start))
    bus = make_bus()
    s = store()
    s.add(1, "weekdays", ["10:00", "14:00"])
    tree = FakeTree(bus, clock, reject)

    def start_tour(tour_id: int, source: str, request_id: str) -> str:
        bus.publish(OPERATOR, OperatorCommand(clock.now(), "start_tour", source=source,
                                              request_id=request_id, tour_id=tour_id))
        return request_id

    sched = Scheduler(s, start_tour, lambda t: f"Tour {t}", bus, clock,
                      ToursConfig(start_window_s=window_s, **kw))
    events_sub = bus.subscribe(EVENTS)
    seen: list[Event] = []

    async def tree_loop() -> None:
        async for _ in clock.every(loop_s):
            tree.answer()
            seen.extend(events_sub.drain())

    return sched, tree, bus, clock, seen, tree_loop  # type: ignore[return-value]


async def run_for(clock: SimClock, seconds: float, *coros: Any) -> None:
    import asyncio

    tasks = [asyncio.create_task(c()) for c in coros]
    await clock.advance(seconds)
    for t in tasks:
        t.cancel()


async def test_a_ready_rover_starts_the_scheduled_tour_on_time() -> None:
    sched, tree, bus, clock, seen, loop = make("09:59")  # type: ignore[misc]
    ready(bus)
    await run_for(clock, 90.0, sched.run, loop)
    (cmd,) = tree.commands
    assert (cmd.action, cmd.tour_id, cmd.source) == ("start_tour", 1, "scheduler")
    assert 60.0 <= cmd.stamp <= 61.0  # 10:00:00, checked every second
    started = [e for e in seen if e.kind == "tour.scheduled_start"]
    assert len(started) == 1 and started[0].detail["due"] == "2025-06-02T10:00+01:00"
    assert not [e for e in seen if e.kind == "tour.skipped"]


async def test_a_busy_rover_delays_then_skips_with_the_reason() -> None:
    sched, tree, bus, clock, seen, loop = make("09:59")  # type: ignore[misc]
    ready(bus, state="needs_help", text="Needs help")
    await run_for(clock, 300.0, sched.run, loop)
    assert tree.commands == []
    delayed = [e for e in seen if e.kind == "tour.delayed"]
    skipped = [e for e in seen if e.kind == "tour.skipped"]
    assert len(delayed) == 1 and delayed[0].detail["reason"] == "the rover is busy (Needs help)"
    assert len(skipped) == 1
    assert skipped[0].detail["reason"] == ("the rover was not ready within 120 s: the rover is "
                                           "busy (Needs help)")
    assert 180.0 <= skipped[0].stamp <= 182.0  # 10:02, the end of the window


async def test_a_rover_ready_within_the_window_starts_late() -> None:
    sched, tree, bus, clock, seen, loop = make("09:59")  # type: ignore[misc]
    ready(bus, state="going_home", text="Going home")
    bus.publish(TOUR, TourState(0.0))
    await run_for(clock, 100.0, sched.run, loop)
    ready(bus)
    await run_for(clock, 30.0, sched.run, loop)
    assert len(tree.commands) == 1
    started = [e for e in seen if e.kind == "tour.scheduled_start"]
    assert started and 39.0 <= started[0].detail["late_s"] <= 42.0


@pytest.mark.parametrize(("setup", "reason"), [
    ({"volts": 6.8}, "the battery is at 6.80 V, below the 7.00 V a tour needs"),
    ({"loc": "lost"}, "the rover is not sure where it is (localisation lost)"),
])
async def test_battery_and_localisation_gate_a_start(setup: dict[str, Any], reason: str) -> None:
    sched, tree, bus, clock, seen, loop = make("09:59")  # type: ignore[misc]
    ready(bus, **setup)
    await run_for(clock, 200.0, sched.run, loop)
    assert tree.commands == []
    assert [e.detail["reason"] for e in seen if e.kind == "tour.skipped"] == [
        f"the rover was not ready within 120 s: {reason}"]


async def test_a_refusal_by_the_tree_is_a_skip_with_its_message() -> None:
    sched, _tree, bus, clock, seen, loop = make(  # type: ignore[misc]
        "09:59", reject="The rover is paused: press Resume first, then start the tour.")
    ready(bus)
    await run_for(clock, 90.0, sched.run, loop)
    (skip,) = [e for e in seen if e.kind == "tour.skipped"]
    assert skip.detail["reason"].startswith("the rover refused it: The rover is paused")


async def test_a_wall_clock_jump_over_a_start_skips_it_as_missed() -> None:
    sched, tree, bus, clock, seen, loop = make("09:00")  # type: ignore[misc]
    ready(bus)
    await run_for(clock, 5.0, sched.run, loop)
    clock.jump_wall(3 * 3600.0)  # 12:00: the 10:00 start is long gone
    await run_for(clock, 5.0, sched.run, loop)
    (skip,) = [e for e in seen if e.kind == "tour.skipped"]
    assert "missed" in skip.detail["reason"] and tree.commands == []


async def test_a_simulated_day_runs_every_start_in_order() -> None:
    sched, _tree, bus, clock, seen, loop = make(  # type: ignore[misc]
        "08:00", loop_s=10.0, check_period_s=10.0)
    sched.schedules.set_closed(["2025-06-03"], "closed")
    ready(bus)
    await run_for(clock, 3 * 86400.0, sched.run, loop)  # Monday to Wednesday
    starts = [e.detail["due"] for e in seen if e.kind == "tour.scheduled_start"]
    assert starts == ["2025-06-02T10:00+01:00", "2025-06-02T14:00+01:00",
                      "2025-06-04T10:00+01:00", "2025-06-04T14:00+01:00"]


def test_readiness_reads_the_bus() -> None:
    bus = make_bus()
    assert readiness(bus, 7.0).reason == "the behaviour tree has not reported its state yet"
    ready(bus)
    assert readiness(bus, 7.0).ready
    bus.publish(TOUR, TourState(0.0, tour_id=2, name="Short"))
    assert readiness(bus, 7.0).reason == "the tour 'Short' is still running"
    bus.publish(TOUR, TourState(0.0))
    bus.publish(LOCALIZATION, LocalizationStatus(0.0, "off"))
    assert readiness(bus, 7.0).ready


def test_a_schedule_edit_the_disk_refused_is_undone_not_saved_later(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Same defect as the paths' (found by curio soak's disk_full).
    import errno

    s = store(tmp_path / "schedules.json")

    def full(path: Path, text: str, private: bool = False) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("curio.tours.files.atomic_write_text", full)
    with pytest.raises(TourError, match="nothing was changed"):
        s.add(1, ["mon"], ["10:00"])
    with pytest.raises(TourError, match="nothing was changed"):
        s.set_closed(["2025-12-25"])
    assert s.list_schedules() == [] and s.closed_days() == []
    monkeypatch.undo()  # the disk has room again
    s.add(2, ["tue"], ["11:00"])
    again = store(tmp_path / "schedules.json")
    assert [(x.id, x.tour_id) for x in again.list_schedules()] == [(1, 2)]
    assert again.closed_days() == []
