"""REST endpoints of tours, schedules and the running tour (aiohttp test client on the real tour
stores, service and scheduler, over a small synthetic map): thin handlers, TourError → 400 with
its sentence, roles (viewers read, operators edit, the kiosk only starts and stops offered
tours with a ``kiosk:<name>`` source), revisions, the schedule editor's refusals."""

from __future__ import annotations

import numpy as np
import pytest

from curio.core.messages import Event, TourState
from curio.core.topics import EVENTS, OPERATOR, TOUR
from tests.web.conftest import (
    ALICE,
    KIOSK,
    TOKEN,
    MakeTourDash,
    bearer,
    ok,
    recv_json_until,
    refused,
)

ADMIN = bearer(TOKEN)
OP = bearer(ALICE)


async def test_viewers_read_operators_edit_the_kiosk_only_starts(
        make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    listing = await ok(await d.client.get("/api/tours"))
    (seed,) = listing["tours"]
    assert seed["name"] == "Tour" and len(seed["stops"]) == 5 and seed["problems"] == []
    assert seed["route"][0] == seed["route"][-1] == [0.0, 0.0]  # home to home
    assert listing["estimate"] == {"speed_mps": 0.2, "detour_factor": 1.4}
    await refused(await d.client.post("/api/tours", json={"name": "X"}), 401,
                   "edit tours and schedules", "token")
    await refused(await d.client.post("/api/tours", json={"name": "X"}, headers=bearer(KIOSK)),
                   403, "kiosk token 'lobby' may only start and stop tours")
    events = d.bus.subscribe(EVENTS)
    made = await ok(await d.client.post("/api/tours", json={"name": " Highlights ",
                                                              "kiosk": False}, headers=OP), 201)
    assert (made["name"], made["stops"], made["kiosk"]) == ("Highlights", [], False)
    assert "has no stops" in made["problems"][0]
    changed = [e for e in events.drain() if e.kind == "tours.changed"]
    assert changed[-1].detail == {"change": "created", "tour_id": made["id"], "actor": "alice"}


async def test_stops_on_the_map_are_checked_and_revisions_guard_edits(
        make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    t = await ok(await d.client.post("/api/tours", json={"name": "Wing"}, headers=OP), 201)
    url = f"/api/tours/{t['id']}"
    stop = {"name": "Desk", "x_m": 2.0, "y_m": 1.0, "dwell_s": 5.0, "message": "Hello"}
    t = await ok(await d.client.post(f"{url}/stops", json={"stop": stop, "revision": 1},
                                      headers=OP), 201)
    assert t["revision"] == 2 and t["stops"][0]["message"]["text"] == "Hello"
    # In the wall block, off the map, a stale revision: one sentence each, nothing changed.
    await refused(await d.client.post(f"{url}/stops", json={"stop": {**stop, "x_m": 8.5}},
                                       headers=OP), 400, "inside an obstacle")
    await refused(await d.client.post(f"{url}/stops", json={"stop": {**stop, "x_m": 40.0}},
                                       headers=OP), 400, "outside the map", "x -5 to 25")
    await refused(await d.client.post(f"{url}/stops", json={"stop": stop, "revision": 1},
                                       headers=OP), 400, "changed meanwhile",
                   "reload it and edit again")
    await refused(await d.client.post(f"{url}/stops", json={"stop": stop, "revision": "2"},
                                       headers=OP), 400, "revision must be a whole number")
    # Click (and drag for the heading) two more; drag one; edit dwell and message; reorder.
    for name, x, yaw in (("Door", 6.0, 1.57), ("Window", 12.0, None)):
        t = await ok(await d.client.post(f"{url}/stops", json={
            "stop": {"name": name, "x_m": x, "y_m": 3.0, "yaw_rad": yaw}}, headers=OP), 201)
    t = await ok(await d.client.patch(f"{url}/stops/0", json={
        "x_m": 3.0, "y_m": 2.0, "dwell_s": 20.0, "message": "Bonjour", "language": "fr",
        "revision": t["revision"]}, headers=OP))
    desk = t["stops"][0]
    assert (desk["x_m"], desk["y_m"], desk["dwell_s"]) == (3.0, 2.0, 20.0)
    assert desk["message"] == {"text": "Bonjour", "language": "fr", "voice": ""}
    await refused(await d.client.patch(f"{url}/stops/0", json={"x_m": 8.5, "y_m": 2.0},
                                        headers=OP), 400, "inside an obstacle")
    await refused(await d.client.patch(f"{url}/stops/0", json={"colour": "red"}, headers=OP),
                   400, "no field 'colour'")
    t = await ok(await d.client.post(f"{url}/order", json={"from": 2, "to": 0}, headers=OP))
    assert [s["name"] for s in t["stops"]] == ["Window", "Desk", "Door"]
    t = await ok(await d.client.post(f"{url}/order", json={"order": [1, 2, 0]}, headers=OP))
    assert [s["name"] for s in t["stops"]] == ["Desk", "Door", "Window"]
    await refused(await d.client.post(f"{url}/order", json={"order": [0, 0, 1]},
                                       headers=OP), 400, "each of its stop numbers 0 to 2")
    t = await ok(await d.client.delete(f"{url}/stops/1?revision={t['revision']}", headers=OP))
    assert [s["name"] for s in t["stops"]] == ["Desk", "Window"]
    est = await ok(await d.client.get(f"{url}/estimate"))
    # home (0,0) → (3,2) → (12,3) → home: straight legs × 1.4 at 0.2 m/s, plus 30 s of dwell
    legs = np.hypot(3, 2) + np.hypot(9, 1) + np.hypot(12, 3)
    assert est["total_s"] == pytest.approx(legs * 1.4 / 0.2 + 30.0, abs=0.2)
    check = await ok(await d.client.post("/api/place-check", json={"x_m": 8.5, "y_m": 2.0}))
    assert check["ok"] is False and "obstacle" in check["problem"]
    assert (await ok(await d.client.post("/api/place-check",
                                          json={"x_m": 3.0, "y_m": 2.0})))["ok"] is True


async def test_rename_offer_duplicate_and_delete(make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    t = await ok(await d.client.patch("/api/tours/1", json={"name": "Highlights",
                                                             "kiosk": False, "revision": 1},
                                       headers=OP))
    assert (t["name"], t["kiosk"], t["revision"]) == ("Highlights", False, 3)
    await refused(await d.client.patch("/api/tours/1", json={"name": "X", "revision": 1},
                                        headers=OP), 400, "changed meanwhile")
    await refused(await d.client.patch("/api/tours/1", json={"colour": 1}, headers=OP),
                   400, "send 'name'")
    copy = await ok(await d.client.post("/api/tours/1/duplicate", json={}, headers=OP), 201)
    assert copy["name"] == "Highlights (copy)" and copy["kiosk"] is False
    await refused(await d.client.post("/api/tours", json={"name": "highlights"}, headers=OP),
                   400, "already a tour called 'Highlights'")
    await ok(await d.client.post("/api/schedules", json={
        "tour_id": copy["id"], "days": ["weekdays"], "times": ["10:00"]}, headers=OP), 201)
    await refused(await d.client.delete(f"/api/tours/{copy['id']}", headers=OP), 400,
                   "was not deleted", "schedule 1 runs it")
    gone = await ok(await d.client.delete(f"/api/tours/{copy['id']}?force=1", headers=OP))
    assert "deleted; schedule 1 removed" in gone["message"]
    assert (await ok(await d.client.get("/api/schedules")))["schedules"] == []
    await refused(await d.client.get(f"/api/tours/{copy['id']}"), 400, "no tour 2")
    await refused(await d.client.get("/api/tours/first"), 400, "tour number must be a whole")


async def test_kiosk_starts_offered_tours_with_its_source(make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    ops = d.bus.subscribe(OPERATOR)
    hidden = await ok(await d.client.post("/api/tours/1/duplicate", json={"name": "Draft"},
                                           headers=OP), 201)
    await refused(await d.client.post(f"/api/tours/{hidden['id']}/start",
                                       headers=bearer(KIOSK)), 403, "not offered at the kiosk")
    await refused(await d.client.post("/api/tours/1/start"), 401, "start and stop tours")
    started = await ok(await d.client.post("/api/tours/1/start", json={"request_id": "k-1"},
                                            headers=bearer(KIOSK)), 202)
    assert started["request_id"] == "k-1"
    (cmd,) = ops.drain()
    assert (cmd.action, cmd.tour_id, cmd.source, cmd.request_id) == (
        "start_tour", 1, "kiosk:lobby", "k-1")
    await refused(await d.client.post("/api/tours/stop", headers=bearer(KIOSK)), 400,
                   "No tour is running")
    d.bus.publish(TOUR, TourState(d.clock.now(), tour_id=1, name="Tour", source="kiosk:lobby",
                                  phase="moving", stop_index=0, stop_name="Lobby",
                                  next_stop_name="Gallery", stops_total=5, eta_s=30.0))
    running = await ok(await d.client.get("/api/tour"))
    assert running["tour"]["stop_name"] == "Lobby" and running["tour"]["eta_s"] == 30.0
    await ok(await d.client.post("/api/tours/stop", headers=bearer(KIOSK)), 202)
    (stop,) = ops.drain()
    assert (stop.action, stop.source) == ("stop_tour", "kiosk:lobby")
    # The operator's generic command carries the tour too (build_command passes tour_id).
    await ok(await d.client.post("/api/command", json={"action": "start_tour", "tour_id": 1},
                                  headers=OP), 202)
    assert [(c.action, c.tour_id, c.source) for c in ops.drain()] == [
        ("start_tour", 1, "web:alice")]
    await refused(await d.client.post("/api/command", json={"action": "start_tour",
                                                              "tour_id": "one"}, headers=OP),
                   400, "tour number must be a whole number")


async def test_the_socket_carries_the_running_tour(make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    async with d.client.ws_connect("/ws", protocols=("curio.v1",)) as ws:
        state = await recv_json_until(ws, lambda m: m.get("t") == "state")
        assert state["tour"] is None
        d.bus.publish(TOUR, TourState(d.clock.now(), tour_id=1, name="Tour", phase="dwelling",
                                      stop_index=1, stop_name="Gallery", message="Art.",
                                      stops_total=5, eta_s=8.0))
        msg = await recv_json_until(ws, lambda m: m.get("t") == "tour")
        assert msg["tour"]["stop_name"] == "Gallery" and msg["tour"]["phase"] == "dwelling"


async def test_schedules_refuse_overlaps_and_show_the_building_time(
        make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    listing = await ok(await d.client.get("/api/schedules"))
    assert listing["timezone"] == "Europe/London"
    assert listing["now_local"] == "2025-06-02T09:00:00+01:00"
    s1 = await ok(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["mon", "wed"], "times": ["10:00", "14:00"], "note": "summer"},
        headers=OP), 201)
    assert s1["tour"] == "Tour" and s1["days"] == ["mon", "wed"]
    why = await refused(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["weekdays"], "times": ["10:05"]}, headers=OP), 400,
        "Overlapping schedules", "Monday", "10:05 tour “Tour” would start before the 10:00")
    assert "or later" in why
    await refused(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["mon"], "times": ["25:00"]}, headers=OP), 400, "not a time")
    await refused(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["someday"], "times": ["11:00"]}, headers=OP), 400,
        "not a weekday")
    await ok(await d.client.patch(f"/api/schedules/{s1['id']}", json={"enabled": False},
                                   headers=OP))
    assert (await ok(await d.client.get("/api/schedule/upcoming")))["upcoming"] == []
    await ok(await d.client.patch(f"/api/schedules/{s1['id']}", json={"enabled": True},
                                   headers=OP))
    up = await ok(await d.client.get("/api/schedule/upcoming?count=3"))
    assert [(u["local"][:16], u["tour"]) for u in up["upcoming"]] == [
        ("2025-06-02T10:00", "Tour"), ("2025-06-02T14:00", "Tour"), ("2025-06-04T10:00", "Tour")]
    closed = await ok(await d.client.put("/api/closed-days", json={
        "dates": ["2025-06-02"], "note": "Bank holiday"}, headers=OP))
    assert closed["closed"] == [{"date": "2025-06-02", "note": "Bank holiday"}]
    up = await ok(await d.client.get("/api/schedule/upcoming?count=1"))
    assert up["upcoming"][0]["local"][:10] == "2025-06-04"
    await refused(await d.client.put("/api/closed-days", json={"dates": ["02/06/2025"]},
                                      headers=OP), 400, "not a date")
    await refused(await d.client.delete("/api/schedules/9", headers=OP), 400, "no schedule 9")
    await refused(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["mon"], "times": ["18:00"]}, headers=bearer(KIOSK)), 403)
    await ok(await d.client.delete(f"/api/schedules/{s1['id']}", headers=ADMIN))


async def test_scheduler_waiting_starts_are_listed_with_the_reason(
        make_tour_dash: MakeTourDash) -> None:
    d = await make_tour_dash()
    await ok(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["mon"], "times": ["09:01"]}, headers=OP), 201)
    d.tours.scheduler.check()
    await d.clock.advance(61.0)  # the check finds the 09:01 start due; no status yet
    d.tours.scheduler.check()
    up = await ok(await d.client.get("/api/schedule/upcoming"))
    (waiting,) = up["waiting"]
    assert waiting["tour"] == "Tour" and "not reported its state" in waiting["reason"]
    assert waiting["until_local"] == "2025-06-02T09:03:00+01:00"


async def test_schedule_edits_name_who_made_them(
        make_tour_dash: MakeTourDash) -> None:
    """A schedule edit is an event naming its operator (the event log records it)."""
    d = await make_tour_dash()
    events = d.bus.subscribe(EVENTS)
    await ok(await d.client.post("/api/schedules", json={
        "tour_id": 1, "days": ["mon"], "times": ["12:00"]}, headers=OP), 201)
    (ev,) = [e for e in events.drain() if isinstance(e, Event)]
    assert (ev.kind, ev.detail["actor"]) == ("schedules.changed", "alice")
