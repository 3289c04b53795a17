"""REST endpoints of the event log, the daily report, the recordings and the replay's timeline
(aiohttp test client on a real SQLite event log and real MCAP files)."""

from __future__ import annotations

import csv
import io

from curio.core.clock import SimClock
from curio.record.timeline import ReplayTimeline
from tests.web.conftest import (
    ALICE,
    TOKEN,
    MakeTourDash,
    at,
    bearer,
    fill_log,
    ok,
    refused,
    write_recording,
)

OP = bearer(ALICE)


async def test_events_are_filtered_paged_and_in_the_buildings_time(
        make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    fill_log(d.log)
    page = await ok(await d.client.get("/api/events?limit=3"))
    assert page["total"] == 10 and len(page["records"]) == 3
    assert page["records"][0]["kind"] == "tour.skipped"  # newest first
    assert page["records"][0]["local"] == "2025-06-02T13:00:00+01:00"
    older = await ok(await d.client.get("/api/events?limit=3&offset=3"))
    assert [r["id"] for r in older["records"]] == sorted(
        (r["id"] for r in older["records"]), reverse=True)
    tours = await ok(await d.client.get("/api/events?kind=tour.&since=2025-06-02"))
    assert [r["kind"] for r in tours["records"]] == [
        "tour.skipped", "tour.finished", "tour.stop", "tour.started"]
    day1 = await ok(await d.client.get(
        "/api/events?since=2025-06-01T09:00&until=2025-06-01T10:05&order=oldest"))
    assert [r["kind"] for r in day1["records"]] == ["tour.started", "tour.stop"]
    text = await ok(await d.client.get("/api/events?text=DOOR"))
    assert [r["kind"] for r in text["records"]] == ["help.requested"]
    src = await ok(await d.client.get("/api/events?source=web:alice"))
    assert [r["kind"] for r in src["records"]] == ["operator.go_home"]
    await refused(await d.client.get("/api/events?since=yesterday"), 400,
                  "since 'yesterday' is not a time", "2025-06-02T10:30")
    await refused(await d.client.get("/api/events?limit=0"), 400, "limit must be 1 or more")


async def test_csv_export_needs_an_operator_and_holds_every_match(
        make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    fill_log(d.log)
    await refused(await d.client.get("/api/events.csv"), 401, "download the event log")
    resp = await d.client.get("/api/events.csv?kind=tour.started,help.", headers=OP)
    assert resp.status == 200 and resp.headers["Content-Type"].startswith("text/csv")
    assert "attachment" in resp.headers["Content-Disposition"]
    rows = list(csv.reader(io.StringIO(await resp.text())))
    assert rows[0] == ["id", "time", "wall_s", "kind", "source", "detail"]
    assert [r[3] for r in rows[1:]] == ["tour.started", "tour.started", "help.requested",
                                        "help.resolved"]  # oldest first
    assert rows[1][1].startswith("2025-06-01T10:00:00") and rows[1][4] == "kiosk:lobby"


async def test_csv_export_is_streamed_in_chunks(make_tour_dash: MakeTourDash,
                                                monkeypatch: object) -> None:
    import curio.web.log_api as log_api

    d = await make_tour_dash()
    fill_log(d.log)
    monkeypatch.setattr(log_api, "CSV_CHUNK", 3)  # type: ignore[attr-defined]
    text = await (await d.client.get("/api/events.csv", headers=OP)).text()
    rows = list(csv.reader(io.StringIO(text)))
    assert rows.count(["id", "time", "wall_s", "kind", "source", "detail"]) == 1
    assert sorted(int(r[0]) for r in rows[1:]) == list(range(1, 11))


async def test_daily_report_and_the_days_for_the_plots(make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    fill_log(d.log)
    today = await ok(await d.client.get("/api/report"))  # the clock says 2 June
    assert today["day"] == "2025-06-02" and today["tours_completed"] == 1
    assert today["help_median_wait_s"] == 42.0 and today["tours_skipped"] == 1
    assert today["skipped"][0]["reason"] == "the battery is low"
    days = await ok(await d.client.get("/api/report/days?from=2025-05-31&to=2025-06-02"))
    assert [(x["day"], x["tours_started"], x["help_median_wait_s"]) for x in days["days"]] == [
        ("2025-05-31", 0, None), ("2025-06-01", 1, None), ("2025-06-02", 1, 42.0)]
    assert len((await ok(await d.client.get("/api/report/days")))["days"]) == 14
    await refused(await d.client.get("/api/report?day=2.6.2025"), 400, "not a date")
    await refused(await d.client.get("/api/report/days?from=2025-01-01&to=2025-06-02"), 400,
                  "at most 92 days")
    await refused(await d.client.get("/api/report/days?from=2025-06-03&to=2025-06-02"), 400,
                  "is after")


async def test_recordings_list_what_happened_and_download(make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    fill_log(d.log)
    name = write_recording(d.recordings, at("09:59"),
                           ["nav.goal_succeeded", "collision", "path.finished"])
    listing = await ok(await d.client.get("/api/recordings"))
    (rec,) = listing["recordings"]
    assert rec["name"] == name and rec["complete"] and rec["duration_s"] == 120.0
    assert rec["start_local"] == "2025-06-02T09:59:00+01:00"
    assert rec["summary"] == "1 collision, 1 nav.goal_succeeded, 1 path.finished"
    assert rec["log"]["text"] == "1 tour"  # 10:00 on 2 June is inside 09:59–10:01
    assert rec["replay"]["laptop"] == f"curio replay {name} --web"
    await refused(await d.client.get(f"/api/recordings/{name}"), 401, "download")
    resp = await d.client.get(f"/api/recordings/{name}", headers=OP)
    assert resp.status == 200 and (await resp.read()).startswith(b"\x89MCAP0\r\n")
    assert f'filename="{name}"' in resp.headers["Content-Disposition"]
    await refused(await d.client.get("/api/recordings/..%2Fevents.sqlite3", headers=OP), 404,
                  "not a plain file name")
    await refused(await d.client.get("/api/recordings/nothing.mcap", headers=OP), 404,
                  "no recording named 'nothing.mcap'")


async def test_the_live_rover_has_no_timeline(make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    assert await ok(await d.client.get("/api/replay")) == {"active": False}
    await refused(await d.client.post("/api/replay", json={"action": "pause"},
                                      headers=bearer(TOKEN)), 409, "not a replay")


async def test_the_replay_timeline_pauses_and_seeks(make_tour_dash: MakeTourDash) -> None:
    timeline = ReplayTimeline("run.mcap", t0_s=100.0, end_s=60.0, speed=None)
    d = await make_tour_dash(replay=timeline)
    clock = SimClock(start_s=100.0)
    timeline.new_run(clock)
    status = await ok(await d.client.get("/api/replay"))
    assert (status["active"], status["file"], status["end_s"], status["position_s"]) == (
        True, "run.mcap", 60.0, 0.0)
    await refused(await d.client.post("/api/replay", json={"action": "pause"}), 401)
    paused = await ok(await d.client.post("/api/replay", json={"action": "pause"},
                                          headers=OP), 202)
    assert paused["paused"] is True
    seek = await ok(await d.client.post("/api/replay", json={"action": "seek", "t_s": 30.0},
                                        headers=OP), 202)
    assert seek["seek"] == "forward" and seek["seeking_to_s"] == 30.0
    await refused(await d.client.post("/api/replay", json={"action": "seek", "t_s": 99},
                                      headers=OP), 400, "seek to a time from 0 to 60.0 s")
    await refused(await d.client.post("/api/replay", json={"action": "rewind"}, headers=OP),
                  400, "unknown action")
    speed = await ok(await d.client.post("/api/replay", json={"action": "speed", "speed": 2},
                                         headers=OP), 202)
    assert speed["speed"] == 2.0
