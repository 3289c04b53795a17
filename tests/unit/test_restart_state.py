"""What a restarted rover knows from its data directory (found by ``curio soak``'s ``kill -9``
faults): that the last run ended uncleanly (``system.unclean_restart``, ``/health`` process),
which tour it interrupted (``tour.interrupted``, counted in the daily report), and where it was
(``last_pose.json``: it starts localised there, not at home)."""

from __future__ import annotations

import asyncio
import datetime as dt
import json
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event, LocalizationStatus, PoseWithCovariance
from curio.core.runmarker import RunMarker
from curio.core.topics import EVENTS, HEALTH, LOCALIZATION, POSE, make_bus
from curio.estimation.last_pose import LastPoseKeeper, load_last_pose
from curio.estimation.wiring import start_pose
from curio.eventlog.report import daily_report
from curio.eventlog.store import EventLog
from curio.robot import RobotModel
from curio.tours.journal import TourJournal


async def _run_for(clock: SimClock, coro: object, seconds: float) -> None:
    task = asyncio.ensure_future(coro)  # type: ignore[call-overload]
    await clock.advance(seconds)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)


async def test_a_tour_cut_short_is_reported_once_at_the_next_start(tmp_path: Path) -> None:
    path = tmp_path / "tours.running.json"
    clock, bus = SimClock(), make_bus()
    journal = TourJournal(path, bus, clock)
    task = asyncio.create_task(journal.run())
    bus.publish(EVENTS, Event(0.0, "tour.started", {"tour_id": 2, "tour": "North wing",
                                                    "source": "scheduler", "request_id": "s-1",
                                                    "stops": 2}))
    await clock.advance(1.0)
    bus.publish(EVENTS, Event(1.0, "tour.stop", {"name": "Library"}))
    await clock.advance(1.0)
    task.cancel()  # kill -9: nothing more happens in this process
    assert json.loads(path.read_text())["stops_reached"] == 1
    bus2 = make_bus()
    events = bus2.subscribe(EVENTS)
    await _run_for(clock, TourJournal(path, bus2, clock).run(), 1.0)
    interrupted = [e for e in events.drain() if e.kind == "tour.interrupted"]
    assert len(interrupted) == 1
    detail = interrupted[0].detail
    assert (detail["tour"], detail["stops_reached"], detail["request_id"]) == (
        "North wing", 1, "s-1")
    assert "did not resume" in detail["message"]
    assert not path.exists()
    bus3 = make_bus()
    events3 = bus3.subscribe(EVENTS)
    await _run_for(clock, TourJournal(path, bus3, clock).run(), 1.0)
    assert events3.drain() == []


async def test_a_tour_started_on_a_full_disk_is_written_once_there_is_room(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Soak finding (seed 2, 2026-12-03): the disk was full at ``tour.started``, the journal
    gave up, and the ``kill -9`` later in the tour left nothing to report. The write is now
    tried again until it succeeds."""
    from curio.tours import journal as journal_module

    room = {"free": False}
    real_write = journal_module.atomic_write_json

    def write(path: Path, data: object) -> None:
        if not room["free"]:
            raise OSError(28, "No space left on device")
        real_write(path, data)

    monkeypatch.setattr(journal_module, "atomic_write_json", write)
    path = tmp_path / "tours.running.json"
    clock, bus = SimClock(), make_bus()
    journal = TourJournal(path, bus, clock)
    task = asyncio.create_task(journal.run())
    bus.publish(EVENTS, Event(0.0, "tour.started", {"tour_id": 1, "tour": "Highlights",
                                                    "stops": 2}))
    await clock.advance(5.0)
    assert not path.exists() and journal.unsaved
    room["free"] = True
    await clock.advance(journal_module.RETRY_S + 0.5)
    task.cancel()  # kill -9
    await asyncio.gather(task, return_exceptions=True)
    assert json.loads(path.read_text())["tour"] == "Highlights"
    bus2 = make_bus()
    events = bus2.subscribe(EVENTS)
    await _run_for(clock, TourJournal(path, bus2, clock).run(), 1.0)
    assert [e.detail["tour"] for e in events.drain() if e.kind == "tour.interrupted"] == [
        "Highlights"]


async def test_a_finished_tour_leaves_nothing_to_report(tmp_path: Path) -> None:
    path = tmp_path / "tours.running.json"
    clock, bus = SimClock(), make_bus()
    task = asyncio.create_task(TourJournal(path, bus, clock).run())
    bus.publish(EVENTS, Event(0.0, "tour.started", {"tour_id": 1, "tour": "Highlights"}))
    await clock.advance(1.0)
    bus.publish(EVENTS, Event(1.0, "tour.finished", {"tour_id": 1}))
    await clock.advance(1.0)
    task.cancel()
    assert not path.exists()


async def test_an_unclean_stop_is_reported_at_the_next_start(tmp_path: Path) -> None:
    path = tmp_path / "running.json"
    clock, bus = SimClock(), make_bus()
    first = RunMarker(path, bus, clock)
    events, health = bus.subscribe(EVENTS), bus.subscribe(HEALTH, maxsize=100)
    await _run_for(clock, first.run(), 2.0)  # then killed: no close()
    assert events.drain() == [] and health.drain()[-1].state == "ok"
    second = RunMarker(path, bus, clock, recent_s=60.0)
    await _run_for(clock, second.run(), 2.0)
    unclean = [e for e in events.drain() if e.kind == "system.unclean_restart"]
    assert len(unclean) == 1 and "unclean stop" in unclean[0].detail["message"]
    assert health.drain()[-1].state == "degraded"
    await second.close()  # a clean stop this time
    third = RunMarker(path, bus, clock)
    await _run_for(clock, third.run(), 2.0)
    assert not third.unclean and events.drain() == []


async def test_the_localised_pose_is_kept_and_a_restart_starts_there(tmp_path: Path) -> None:
    cfg = Config(data_dir=str(tmp_path))
    robot = RobotModel.from_config(cfg.robot)
    assert start_pose(cfg, robot) == robot.home
    clock, bus = SimClock(), make_bus()
    keeper = LastPoseKeeper(cfg.data_path("last_pose.json"), bus, clock)
    task = asyncio.create_task(keeper.run())
    bus.publish(LOCALIZATION, LocalizationStatus(0.0, "ok"))
    bus.publish(POSE, PoseWithCovariance(0.0, Pose2D(3.0, 4.0, 0.5)))
    await clock.advance(1.5)
    bus.publish(LOCALIZATION, LocalizationStatus(1.5, "lost"))
    bus.publish(POSE, PoseWithCovariance(1.5, Pose2D(9.0, 9.0, 0.0)))  # not trusted
    await clock.advance(1.5)
    task.cancel()
    assert load_last_pose(cfg.data_path("last_pose.json")) == Pose2D(3.0, 4.0, 0.5)
    assert start_pose(cfg, robot) == Pose2D(3.0, 4.0, 0.5)
    off = cfg.model_copy(update={"localization": cfg.localization.model_copy(
        update={"resume_last_pose": False})})
    assert start_pose(off, robot) == robot.home


def test_a_corrupt_last_pose_is_ignored(tmp_path: Path) -> None:
    path = tmp_path / "last_pose.json"
    path.write_text('{"x_m": 1.0, "y_m"')
    assert load_last_pose(path) is None


def test_the_daily_report_counts_interrupted_tours(tmp_path: Path) -> None:
    tz = ZoneInfo("UTC")
    day = dt.date(2025, 6, 2)
    t0 = dt.datetime(2025, 6, 2, 10, 0, tzinfo=tz).timestamp()
    log = EventLog(tmp_path / "events.sqlite3")
    log.append("tour.started", {"tour": "Highlights", "stops": 2}, wall_s=t0)
    log.append("tour.interrupted", {"tour": "Highlights", "stops_reached": 1}, wall_s=t0 + 90)
    assert log.flush()
    report = daily_report(log, day, tz)
    log.close()
    assert report.tours_interrupted == 1 and report.tours_stopped == 0
    assert report.tours[0]["outcome"] == "interrupted"
