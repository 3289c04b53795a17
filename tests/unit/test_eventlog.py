"""The event log: batched writes off the loop, queries with filters, CSV, bounds, restarts,
a real process killed with SIGKILL, a corrupt database, and the recorder on the bus."""

from __future__ import annotations

import csv
import ctypes
import ctypes.util
import io
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from curio.core.clock import SimClock, wall_perf_counter
from curio.core.config import EventLogConfig
from curio.core.geometry import Pose2D
from curio.core.messages import DriverHealth, EStop, Event, Odometry, OperatorCommand
from curio.core.topics import ESTOP, EVENTS, HEALTH, ODOM, OPERATOR, make_bus
from curio.eventlog.commands import CommandJournal
from curio.eventlog.recorder import EventRecorder
from curio.eventlog.store import EventLog, EventLogError, LogQuery

T0 = 1_750_000_000.0


def test_append_flush_query_filters_and_csv(tmp_path: Path) -> None:
    log = EventLog(tmp_path / "events.sqlite3", batch_rows=7)
    for i in range(50):
        kind = ("tour.started", "tour.skipped", "operator.go_home", "help.requested")[i % 4]
        log.append(kind, {"i": i, "reason": "busy" if i % 4 == 1 else ""}, wall_s=T0 + i,
                   source="scheduler" if i % 4 == 1 else "web")
    assert log.flush()
    assert log.stats.written == 50 and log.stats.batches >= 50 // 7
    assert log.count() == 50
    tours = log.query(LogQuery(kinds=("tour.",)))
    assert len(tours) == 26 and {r.kind for r in tours} == {"tour.started", "tour.skipped"}
    window = log.query(LogQuery(since_wall_s=T0 + 10, until_wall_s=T0 + 20))
    assert [r.detail["i"] for r in window] == list(range(10, 20))
    newest = log.query(LogQuery(kinds=("help.requested",), newest_first=True, limit=2))
    assert [r.detail["i"] for r in newest] == [47, 43]
    assert log.count(LogQuery(source="scheduler", text="BUSY")) == 13
    assert log.query(LogQuery(limit=5, offset=45))[0].detail["i"] == 45
    out = io.StringIO()
    n = log.export_csv(out, LogQuery(kinds=("tour.skipped",)), ZoneInfo("Europe/London"))
    rows = list(csv.reader(io.StringIO(out.getvalue())))
    assert n == 13 and rows[0] == ["id", "time", "wall_s", "kind", "source", "detail"]
    assert rows[1][1] == "2025-06-15T16:06:41.000+01:00" and rows[1][3] == "tour.skipped"
    assert '"reason": "busy"' in rows[1][5]
    log.close()


def test_survives_a_restart_and_is_bounded_by_size_and_age(tmp_path: Path) -> None:
    path = tmp_path / "events.sqlite3"
    log = EventLog(path, max_rows=1000, prune_every=100, max_age_days=1.0)
    for i in range(1500):
        log.append("old" if i < 200 else "new", {"i": i}, wall_s=T0 + i)
    log.close()
    reopened = EventLog(path, max_rows=1000, prune_every=100, max_age_days=1.0)
    assert reopened.count() <= 1000 + 100
    assert reopened.query(LogQuery(limit=1))[0].detail["i"] >= 400
    reopened.append("new", {"i": 9999}, wall_s=T0 + 2 * 86400)  # two days later
    reopened.prune_now()
    reopened.append("new", {"i": 10000}, wall_s=T0 + 2 * 86400 + 1)
    reopened.flush()
    assert [r.detail["i"] for r in reopened.query()] == [9999, 10000]  # older than a day: gone
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    reopened.close()


WRITER = textwrap.dedent("""
    import sys
    from curio.eventlog.store import EventLog
    log = EventLog(sys.argv[1], batch_rows=64)
    i = 0
    while True:
        for _ in range(50):
            log.append("tick", {"i": i, "pad": "x" * 200}, wall_s=1.0 + i)
            i += 1
        log.flush()
        print(i, flush=True)
""")


def test_committed_records_survive_kill_9(tmp_path: Path) -> None:
    path = tmp_path / "events.sqlite3"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdout is not None
    committed = 0
    try:
        while committed < 3000:
            line = proc.stdout.readline()
            assert line, "the writer process died"
            committed = int(line)
        os.kill(proc.pid, signal.SIGKILL)  # in the middle of writing more
    finally:
        proc.kill()
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    log = EventLog(path)  # reopens (and recovers the WAL) without complaint
    ids = [r.detail["i"] for r in log.iter_query(LogQuery(limit=100_000))]
    assert len(ids) >= committed and ids == list(range(len(ids)))  # nothing lost, no gaps
    log.append("after", {}, wall_s=1e6)
    log.flush()
    assert log.count(LogQuery(kinds=("after",))) == 1
    log.close()


def test_a_corrupt_database_is_refused_with_the_file(tmp_path: Path) -> None:
    path = tmp_path / "events.sqlite3"
    path.write_bytes(b"this is not a database" * 100)
    with pytest.raises(EventLogError, match=f"the event log {path} cannot be used"):
        EventLog(path)
    with pytest.raises(EventLogError, match="there is no event log at"):
        EventLog(tmp_path / "none.sqlite3", readonly=True)


async def test_the_recorder_logs_events_estops_faults_and_motion_the_journal_commands(
        tmp_path: Path) -> None:
    clock = SimClock(epoch_wall_s=T0)
    bus = make_bus()
    log = EventLog(tmp_path / "events.sqlite3")
    rec = EventRecorder(log, bus, clock, EventLogConfig(motion_summary_s=10.0,
                                                        ignore_kinds=["nav."]))
    journal = CommandJournal(bus, clock, log)
    bus.publish(OPERATOR, OperatorCommand(0.0, "start_tour", source="kiosk", request_id="r1",
                                          tour_id=2))
    answer = Event(0.0, "bt.command_accepted", {"request_id": "r1", "message": "Starting."})
    bus.publish(EVENTS, Event(0.0, "tour.started", {"tour_id": 2, "source": "kiosk"}))
    bus.publish(EVENTS, answer)
    bus.publish(EVENTS, Event(0.0, "nav.goal_accepted", {}))
    bus.publish(ESTOP, EStop(0.0, False))
    bus.publish(HEALTH, DriverHealth(0.0, "lidar", "ok"))
    journal.poll()
    rec.poll()  # not the answer: the journal writes it
    await journal.deliver(answer)
    await clock.advance(2.0)
    bus.publish(ESTOP, EStop(clock.now(), True, "web", "operator"))
    bus.publish(HEALTH, DriverHealth(clock.now(), "lidar", "error", "no scans"))
    for i in range(11):  # 1 m in 10 s at 0.1 m/s
        bus.publish(ODOM, Odometry(clock.now(), Pose2D(0.1 * i, 0.0, 0.0), 0.1))
        rec.poll()
        await clock.advance(1.0)
    bus.publish(HEALTH, DriverHealth(clock.now(), "lidar", "ok"))
    bus.publish(ESTOP, EStop(clock.now(), False, "web"))
    rec.close()
    log.close()
    got = EventLog(tmp_path / "events.sqlite3", readonly=True).query()
    kinds = [r.kind for r in got if r.kind != "motion"]
    assert kinds == ["operator.start_tour", "tour.started", "bt.command_accepted",
                     "estop.engaged", "fault", "estop.released", "fault.cleared"]
    op = got[0]
    assert (op.source, op.detail, op.wall_s) == ("kiosk", {"request_id": "r1", "tour_id": 2}, T0)
    assert got[4].detail == {"name": "lidar", "state": "error", "message": "no scans"}
    assert got[3].wall_s == pytest.approx(T0 + 2.0)
    motion = [r.detail for r in got if r.kind == "motion"]
    assert len(motion) == 2  # one every 10 s of clock time, the rest at close
    assert sum(m["distance_m"] for m in motion) == pytest.approx(1.0)
    assert sum(m["moving_s"] for m in motion) == pytest.approx(10.0)


class _TinyDisk(EventLog):
    """An event log whose database may not grow past ``pages`` pages: SQLite's own
    ``SQLITE_FULL`` ("database or disk is full"), as on a full disk."""

    pages = 10**6

    def _write(self, conn: sqlite3.Connection, rows: list) -> None:  # type: ignore[type-arg]
        conn.execute(f"PRAGMA max_page_count={self.pages}")
        super()._write(conn, rows)


def test_records_written_while_the_disk_is_full_are_kept_and_written_later(
        tmp_path: Path) -> None:
    # Found by curio soak (disk_full): a full disk lost every record written meanwhile, and
    # the log's health stayed 'degraded' for ever after one failed write.
    log = _TinyDisk(tmp_path / "events.sqlite3")
    for i in range(20):
        log.append("before", {"i": i, "pad": "x" * 400}, wall_s=T0 + i)
    assert log.flush()
    log.pages = 1
    for i in range(30):
        log.append("during", {"i": i, "pad": "x" * 400}, wall_s=T0 + 100 + i)
    assert not log.flush(timeout_s=3.0)  # not committed: the disk is full
    assert log.stats.failing and log.stats.retrying == 30 and log.stats.lost == 0
    log.pages = 10**6  # space again
    assert log.flush(timeout_s=10.0)
    assert not log.stats.failing and log.stats.retrying == 0
    assert log.count(LogQuery(kinds=("during",))) == 30 and log.count() == 50
    log.close()


def test_a_write_ahead_on_a_full_disk_gives_up_soon_and_is_written_later(
        tmp_path: Path) -> None:
    log = _TinyDisk(tmp_path / "events.sqlite3")
    assert log.append_committed("operator.pause", {"request_id": "a"}, wall_s=T0)
    log.pages = 1
    for i in range(20):  # fill the last pages
        log.append("pad", {"i": i, "pad": "x" * 400}, wall_s=T0 + i)
    assert not log.append_committed("operator.pause", {"request_id": "b"}, wall_s=T0 + 30,
                                    timeout_s=0.5)  # the first failure: waited, in vain
    assert log.stats.failing
    t0 = wall_perf_counter()
    assert not log.append_committed("operator.pause", {"request_id": "c"}, wall_s=T0 + 31)
    assert wall_perf_counter() - t0 < 0.1  # known to be failing: no wait at all
    log.pages = 10**6
    assert log.flush(timeout_s=10.0)
    assert [r.detail["request_id"] for r in log.query(LogQuery(kinds=("operator.",)))] == [
        "a", "b", "c"]
    log.close()


def test_beyond_the_retry_bound_the_oldest_are_dropped_and_counted(tmp_path: Path) -> None:
    log = _TinyDisk(tmp_path / "events.sqlite3", max_retry_rows=10)
    log.pages = 1
    for i in range(25):
        log.append("during", {"i": i, "pad": "x" * 2000}, wall_s=T0 + i)
    log.flush(timeout_s=3.0)
    log.pages = 10**6
    assert log.flush(timeout_s=10.0)
    assert log.stats.lost == 15
    assert [r.detail["i"] for r in log.query()] == list(range(15, 25))
    log.close()


async def test_the_logs_health_recovers_when_writes_work_again(tmp_path: Path) -> None:
    clock = SimClock(epoch_wall_s=T0)
    bus = make_bus()
    health = bus.subscribe(HEALTH, maxsize=100)
    log = _TinyDisk(tmp_path / "events.sqlite3")
    rec = EventRecorder(log, bus, clock, EventLogConfig())
    log.pages = 1
    bus.publish(EVENTS, Event(0.0, "tour.started", {"pad": "x" * 5000}))
    rec.poll()
    log.flush(timeout_s=3.0)
    await clock.advance(6.0)
    rec.poll()
    states = [h.state for h in health.drain() if h.name == "eventlog"]
    assert states[-1] == "degraded"
    log.pages = 10**6
    assert log.flush(timeout_s=10.0)
    await clock.advance(6.0)
    rec.poll()
    assert [h.state for h in health.drain() if h.name == "eventlog"][-1] == "ok"
    rec.close()
    log.close()
    kinds = [r.kind for r in EventLog(tmp_path / "events.sqlite3", readonly=True).query()]
    assert "tour.started" in kinds and "fault" in kinds and "fault.cleared" in kinds


def test_the_writer_keeps_a_small_page_cache(tmp_path: Path) -> None:
    """The writer's SQLite memory stays small while the file grows (with SQLite's default 2 MB
    page cache it grew by 2.0 MB over these 30 000 records: a slow RSS growth over hours)."""
    libsqlite = ctypes.CDLL(ctypes.util.find_library("sqlite3") or "libsqlite3.so.0")
    libsqlite.sqlite3_memory_used.restype = ctypes.c_int64
    log = EventLog(tmp_path / "events.sqlite3")
    assert log.flush()
    before = libsqlite.sqlite3_memory_used()
    for i in range(30_000):
        log.append("nav.goal_succeeded", {"note": "goal reached", "goal_id": i, "x": 1.2345,
                                          "y": 2.3456, "tag": "scenario goto"},
                   wall_s=1.7e9 + i)
        if i % 1000 == 999:
            assert log.flush()
    assert log.flush()
    grown = libsqlite.sqlite3_memory_used() - before
    log.close()
    assert grown < 0.6e6, f"SQLite's memory grew by {grown / 1e6:.2f} MB"
