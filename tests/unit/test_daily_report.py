"""The daily report from the event log, and ``curio report --day`` (bad dates: one line,
exit 2)."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from curio.cli import main
from curio.eventlog.report import daily_report, format_report
from curio.eventlog.store import EventLog

TZ = ZoneInfo("Europe/Paris")
DAY = dt.date(2025, 6, 2)


def at(hhmm: str, day: dt.date = DAY) -> float:
    h, m = map(int, hhmm.split(":"))
    return dt.datetime(day.year, day.month, day.day, h, m, tzinfo=TZ).timestamp()


def fill(path: Path) -> None:
    log = EventLog(path)
    rows = [
        ("08:59", "tour.started", {"tour": "Yesterday's", "source": "web"}, dt.date(2025, 6, 1)),
        ("09:00", "operator.start_tour", {"tour_id": 1}, DAY),
        ("09:00", "tour.scheduled_start", {"tour": "Highlights"}, DAY),
        ("09:00", "tour.started", {"tour": "Highlights", "source": "scheduler", "stops": 2}, DAY),
        ("09:03", "tour.stop", {"name": "Lobby"}, DAY),
        ("09:05", "help.requested", {}, DAY),
        ("09:07", "help.resolved", {"waited_s": 120.0, "reason": "clear"}, DAY),
        ("09:08", "tour.stop", {"name": "Gallery"}, DAY),
        ("09:09", "motion", {"distance_m": 40.0, "moving_s": 200.0}, DAY),
        ("09:10", "tour.finished", {"stops_reached": 2, "duration_s": 600.0}, DAY),
        ("10:00", "tour.skipped", {"tour": "North wing", "due": "2025-06-02T10:00+02:00",
                                   "reason": "the rover is busy (Needs help)"}, DAY),
        ("11:00", "tour.started", {"tour": "Short", "source": "kiosk:visitor", "stops": 1}, DAY),
        ("11:01", "help.requested", {}, DAY),
        ("11:02", "help.resolved", {"waited_s": 30.0, "reason": "help_done"}, DAY),
        ("11:03", "help.resolved", {"waited_s": 1.0, "reason": "preempted"}, DAY),
        ("11:04", "fault", {"name": "lidar", "state": "error", "message": "no scans"}, DAY),
        ("11:05", "estop.engaged", {}, DAY),
        ("11:06", "tour.stopped", {"stops_reached": 0, "reason": "E-stop"}, DAY),
        ("11:07", "motion", {"distance_m": 2.5, "moving_s": 10.0}, DAY),
        ("00:30", "tour.started", {"tour": "Tomorrow's"}, dt.date(2025, 6, 3)),
    ]
    for hhmm, kind, detail, day in rows:
        log.append(kind, detail, wall_s=at(hhmm, day))
    log.close()


def test_the_report_counts_the_day_in_local_time(tmp_path: Path) -> None:
    fill(tmp_path / "events.sqlite3")
    r = daily_report(EventLog(tmp_path / "events.sqlite3", readonly=True), DAY, TZ)
    assert (r.tours_started, r.tours_completed, r.tours_stopped) == (2, 1, 1)
    assert (r.tours_scheduled, r.tours_scheduled_started, r.tours_skipped) == (2, 1, 1)
    assert r.stops_visited == 2 and r.distance_m == 42.5 and r.moving_s == 210.0
    assert r.help_requests == 2 and r.help_waits_s == [120.0, 30.0]
    assert r.help_median_wait_s == 75.0
    assert (r.faults, r.estops, r.collisions, r.operator_commands) == (1, 1, 0, 1)
    assert r.events == 18
    assert r.tours[0] == {"time": "09:00", "tour": "Highlights", "source": "scheduler",
                          "outcome": "completed", "reason": "", "stops_reached": 2,
                          "stops": 2, "duration_s": 600.0}
    assert r.tours[1]["source"] == "kiosk" and r.tours[1]["reason"] == "E-stop"
    assert r.skipped == [{"due": "10:00", "tour": "North wing",
                          "reason": "the rover is busy (Needs help)"}]
    text = format_report(r)
    assert "tours run: 2 (completed 1, stopped 1)" in text
    assert "median wait for help: 75 s" in text
    assert "10:00 North wing: the rover is busy (Needs help)" in text


def cli(tmp_path: Path, *args: str) -> int:
    return main(["report", *args, "--set", f'data_dir="{tmp_path}"', "--set",
                 'tours.timezone="Europe/Paris"'])


def test_curio_report_prints_the_day_and_writes_csv(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fill(tmp_path / "events.sqlite3")
    assert cli(tmp_path, "--day", "2025-06-02", "--csv", str(tmp_path / "day.csv")) == 0
    out = capsys.readouterr()
    assert "Curio daily report for 2025-06-02 (Europe/Paris)" in out.out
    assert "wrote 18 records" in out.err
    assert len((tmp_path / "day.csv").read_text().splitlines()) == 19
    assert cli(tmp_path, "--day", "2025-06-02", "--json") == 0
    assert json.loads(capsys.readouterr().out)["tours_completed"] == 1


@pytest.mark.parametrize("day", ["2025-13-01", "yesterday", "2025-02-30", ""])
def test_a_bad_date_is_one_line_and_exit_2(tmp_path: Path, day: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    fill(tmp_path / "events.sqlite3")
    assert cli(tmp_path, "--day", day) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a date; use YYYY-MM-DD" in err


def test_no_event_log_is_one_line_and_exit_2(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(tmp_path, "--day", "2025-06-02") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "there is no event log at" in err


def test_curio_run_refuses_a_corrupt_tours_file_with_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "tours.json").write_text('{"version": 2, "tours": [')
    code = main(["run", "--set", f'data_dir="{tmp_path}"', "--set", "web.enabled=false"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert f"the tours file {tmp_path / 'tours.json'} cannot be used: it is not valid JSON" in err
    assert (tmp_path / "tours.json").read_text() == '{"version": 2, "tours": ['
