"""Several operators: named tokens and roles, the e-stop that is always accepted, who set and
released it, the teleop lease, who did what, concurrent path edits, revoked tokens."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import aiohttp
import pytest
from aiohttp import WSMsgType

from curio.core.messages import EStop
from curio.core.topics import CMD_VEL_TELEOP, ESTOP, EVENTS, OPERATOR
from curio.web.tokens import TokenStore
from tests.web.conftest import (
    ALICE,
    BOB,
    KIOSK,
    TOKEN,
    Dash,
    MakeDash,
    bearer,
    recv_json_until,
)


async def ws_for(d: Dash, token: str | None) -> aiohttp.ClientWebSocketResponse:
    """A socket that presents ``token`` the way the page does (a subprotocol)."""
    protocols = ("curio.v1",) + ((f"curio.token.{token}",) if token else ())
    ws = await d.client.ws_connect("/ws", protocols=protocols)
    hello = await ws.receive_json(timeout=5)
    assert hello["t"] == "hello"
    return ws




async def test_each_token_is_a_named_role(make_dash: MakeDash) -> None:
    d = await make_dash()
    for token, name, role in ((None, "viewer", "viewer"), (ALICE, "alice", "operator"),
                              (TOKEN, "admin", "admin"), (KIOSK, "lobby", "kiosk")):
        resp = await d.client.get("/api/auth", headers=bearer(token) if token else {})
        who = (await resp.json())["who"]
        assert (who["name"], who["role"]) == (name, role)
    resp = await d.client.get("/api/auth", headers=bearer("not-a-token-at-all-xxxxxxxx"))
    assert resp.status == 403


async def test_kiosk_may_only_start_and_stop_tours(make_dash: MakeDash) -> None:
    d = await make_dash()
    ops = d.bus.subscribe(OPERATOR)
    for action in ("start_tour", "stop_tour"):
        resp = await d.client.post("/api/command", json={"action": action}, headers=bearer(KIOSK))
        assert resp.status == 202
    assert [(c.action, c.source) for c in ops.drain()] == [
        ("start_tour", "kiosk:lobby"), ("stop_tour", "kiosk:lobby")]
    for path, body in (("/api/command", {"action": "go_home"}), ("/api/estop", {}),
                       ("/api/initial_pose", {"x_m": 0, "y_m": 0, "yaw_rad": 0}),
                       ("/api/paths", {"name": "x"})):
        resp = await d.client.post(path, json=body, headers=bearer(KIOSK))
        assert resp.status == 403, path
        assert "may only start and stop tours" in (await resp.json())["error"]
    ws = await ws_for(d, KIOSK)
    await ws.send_json({"op": "teleop", "seq": 1, "linear_mps": 0.2})
    await ws.send_json({"op": "command", "id": 3, "action": "start_tour"})
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert "may only start and stop tours" in err["message"]
    ack = await recv_json_until(ws, lambda m: m["t"] == "ack")
    assert ack["id"] == 3 and ack["action"] == "start_tour"
    await ws.close()
    assert [c.action for c in ops.drain()] == ["start_tour"]


async def test_estop_is_accepted_after_a_burst_over_rest_and_websocket(
        make_dash: MakeDash) -> None:
    d = await make_dash(max_messages_per_s=20.0)
    ops = d.bus.subscribe(OPERATOR)
    statuses = [(await d.client.post("/api/command", json={"action": "pause"},
                                     headers=bearer(ALICE))).status for _ in range(60)]
    assert statuses.count(429) >= 30  # the burst is limited ...
    for path, body in (("/api/estop", None), ("/api/command", {"action": "estop"})):
        resp = await d.client.post(path, json=body, headers=bearer(ALICE))
        assert resp.status == 202, path  # ... the e-stop never is
    ws = await ws_for(d, ALICE)
    for _ in range(90):  # a burst (fewer than the 100 refusals in a row that disconnect)
        await ws.send_json({"op": "command", "action": "pause"})
    await ws.send_json({"op": "estop", "id": "stop-1"})
    await ws.send_json({"op": "command", "id": "stop-2", "action": "estop"})
    seen: list[dict[str, Any]] = []

    def ack(msg_id: str) -> Callable[[dict[str, Any]], bool]:
        return lambda m: bool(seen.append(m)) or (m["t"] == "ack" and m["id"] == msg_id)

    acks = [await recv_json_until(ws, ack(i)) for i in ("stop-1", "stop-2")]
    assert all(a["action"] == "estop" for a in acks)
    assert not ws.closed
    await ws.close()
    assert any(m["t"] == "error" and m["code"] == "rate_limited" for m in seen)
    estops = [c for c in ops.drain() if c.action == "estop"]
    assert len(estops) == 4 and {c.source for c in estops} == {"web:alice"}
    # The page sends its e-stop both ways with one request id: it is published once.
    for path in ("/api/estop", "/api/estop"):
        resp = await d.client.post(path, json={"request_id": "page-stop-1"},
                                   headers=bearer(ALICE))
        assert resp.status == 202
    assert [c.request_id for c in ops.drain()] == ["page-stop-1"]
    assert sum(c.action == "pause" for c in ops.drain()) < 90


async def test_viewers_cannot_estop_or_drive(make_dash: MakeDash) -> None:
    d = await make_dash()
    ws = await ws_for(d, None)
    await ws.send_json({"op": "estop", "id": 1})
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert err["id"] == 1 and "token" in err["message"]
    await ws.close()
    assert (await d.client.post("/api/estop")).status == 401


async def test_only_the_setter_or_an_admin_releases_an_estop(make_dash: MakeDash) -> None:
    d = await make_dash()
    viewer = await ws_for(d, None)
    d.bus.publish(ESTOP, EStop(1.0, True, source="web:alice", reason="operator pressed e-stop"))
    msg = await recv_json_until(viewer, lambda m: m["t"] == "estop")
    assert msg["log"]["set_by"] == "web:alice" and msg["log"]["set_at"] is not None
    release = {"action": "release_estop"}
    resp = await d.client.post("/api/command", json=release, headers=bearer(BOB))
    assert resp.status == 403
    assert "set by alice; only alice or an admin" in (await resp.json())["error"]
    for token in (ALICE, TOKEN):
        resp = await d.client.post("/api/command", json=release, headers=bearer(token))
        assert resp.status == 202
    d.bus.publish(ESTOP, EStop(2.0, False, source="web:admin", reason="released"))
    msg = await recv_json_until(viewer, lambda m: m["t"] == "estop")
    assert msg["log"]["set_by"] == "web:alice" and msg["log"]["released_by"] == "web:admin"
    state = await (await d.client.get("/api/state")).json()
    assert state["estop_log"]["released_by"] == "web:admin"
    # An e-stop the rover set itself (not a named operator) any operator may release.
    d.bus.publish(ESTOP, EStop(3.0, True, source="safety", reason="no scan"))
    resp = await d.client.post("/api/command", json=release, headers=bearer(BOB))
    assert resp.status == 202
    await viewer.close()


async def test_teleop_lease_one_driver_take_over_and_lapse(make_dash: MakeDash) -> None:
    d = await make_dash(teleop_lease_s=2.0)
    teleop = d.bus.subscribe(CMD_VEL_TELEOP, maxsize=100)
    alice, bob, viewer = await ws_for(d, ALICE), await ws_for(d, BOB), await ws_for(d, None)
    await alice.send_json({"op": "teleop", "seq": 1, "linear_mps": 0.3})
    lease = await recv_json_until(viewer, lambda m: m["t"] == "lease")
    assert lease["lease"]["holder"] == "alice" and lease["lease"]["driving"] is True
    await bob.send_json({"op": "teleop", "seq": 1, "linear_mps": -0.3})
    err = await recv_json_until(bob, lambda m: m["t"] == "error")
    assert err["code"] == "lease_held" and err["holder"] == "alice"
    assert err["message"] == "alice is driving — take over?"
    assert [(m.linear_mps, m.source) for m in teleop.drain()] == [(0.3, "web:alice")]
    await bob.send_json({"op": "teleop", "seq": 2, "linear_mps": -0.2, "take_over": True})
    lease = await recv_json_until(alice, lambda m: m["t"] == "lease" and
                                  m["lease"]["holder"] != "alice")
    assert lease["lease"]["holder"] == "bob"
    event = await recv_json_until(viewer, lambda m: m["t"] == "event" and m["event"]["kind"] ==
                        "operator.teleop" and m["event"]["detail"]["who"] == "bob")
    assert event["event"]["detail"]["what"] == "took over driving from alice"
    await alice.send_json({"op": "teleop", "seq": 2, "linear_mps": 0.3})
    err = await recv_json_until(alice, lambda m: m["t"] == "error")
    assert err["holder"] == "bob"
    assert [(m.linear_mps, m.source) for m in teleop.drain()] == [(-0.2, "web:bob")]
    # Bob lets go; after teleop_lease_s the lease lapses and alice drives without asking.
    await bob.send_json({"op": "teleop", "seq": 3, "linear_mps": 0.0})
    await recv_json_until(viewer, lambda m: m["t"] == "lease" and not m["lease"]["driving"])
    await d.clock.advance(2.5)
    await recv_json_until(viewer, lambda m: m["t"] == "lease" and m["lease"]["holder"] is None)
    await alice.send_json({"op": "teleop", "seq": 3, "linear_mps": 0.1})
    await recv_json_until(viewer, lambda m: m["t"] == "lease" and m["lease"]["holder"] == "alice")
    await alice.close()  # the driver's page goes: the rover stops, the lease is free
    await recv_json_until(viewer, lambda m: m["t"] == "lease" and m["lease"]["holder"] is None)
    assert teleop.drain()[-1].linear_mps == 0.0
    await bob.close()
    await viewer.close()


async def test_every_page_sees_who_did_what(make_dash: MakeDash) -> None:
    d = await make_dash()
    events = d.bus.subscribe(EVENTS)
    bob = await ws_for(d, BOB)
    await d.client.post("/api/command", json={"action": "go_home"}, headers=bearer(ALICE))
    ev = await recv_json_until(bob, lambda m: m["t"] == "event" and m["event"]["kind"] ==
                     "operator.command")
    assert ev["event"]["detail"]["who"] == "alice"
    assert ev["event"]["detail"]["what"] == "sent the rover home"
    assert isinstance(ev["event"]["wall"], float)
    resp = await d.client.delete("/api/paths/2", headers=bearer(ALICE))
    assert resp.status == 200
    paths = await recv_json_until(bob, lambda m: m["t"] == "paths")
    assert (paths["change"], paths["path_id"], paths["by"]) == ("deleted", 2, "alice")
    assert all(p["id"] != 2 for p in paths["paths"])
    kinds = [(e.kind, e.detail["who"]) for e in events.drain() if e.kind.startswith("operator.")]
    assert kinds == [("operator.command", "alice"), ("operator.path", "alice")]
    await bob.close()


async def test_concurrent_path_edits_are_refused_not_lost(make_dash: MakeDash) -> None:
    d = await make_dash()
    path = await (await d.client.get("/api/paths")).json()
    rev = path[1]["rev"]
    resp = await d.client.post("/api/paths/1/waypoints", headers=bearer(ALICE),
                               json={"x_m": 2.0, "y_m": 2.0, "rev": rev})
    assert resp.status == 201
    resp = await d.client.patch("/api/paths/1/waypoints/0", headers=bearer(BOB),
                                json={"x_m": 3.0, "y_m": 3.0, "rev": rev})
    assert resp.status == 409
    assert "changed by alice" in (await resp.json())["error"]
    assert [(w.x_m, w.y_m) for w in d.paths.get(1).waypoints] == [(1.0, 0.0), (2.0, 2.0)]
    fresh = (await resp.json()) and (await (await d.client.get("/api/paths")).json())[1]["rev"]
    resp = await d.client.post("/api/paths/1/waypoints", headers=bearer(BOB),
                               json={"x_m": 0.5, "y_m": 0.5, "index": 1, "rev": fresh})
    assert resp.status == 201  # inserted between the two
    resp = await d.client.put("/api/paths/1/waypoints", headers=bearer(BOB), json={
        "waypoints": [{"x_m": 2, "y_m": 2}, {"x_m": 1, "y_m": 0, "yaw_rad": 1.0}]})
    assert resp.status == 200  # reordered (and one removed)
    assert [(w.x_m, w.yaw_rad) for w in d.paths.get(1).waypoints] == [(2.0, None), (1.0, 1.0)]


async def test_a_revoked_token_is_disconnected(make_dash: MakeDash) -> None:
    d = await make_dash()
    alice, bob = await ws_for(d, ALICE), await ws_for(d, BOB)
    TokenStore(d.tokens.path).revoke("alice")  # what 'curio token revoke alice' does

    async def read_until_closed() -> None:  # a page reads all the time (and answers a close)
        for _ in range(500):
            if (await alice.receive(timeout=5)).type in (WSMsgType.CLOSE, WSMsgType.CLOSED):
                return

    reader = asyncio.ensure_future(read_until_closed())
    await d.clock.advance(1.5)
    await reader
    assert alice.close_code == 4001
    assert not bob.closed
    resp = await d.client.post("/api/command", json={"action": "go_home"}, headers=bearer(ALICE))
    assert resp.status == 403
    await bob.close()


@pytest.mark.parametrize("role", ["operator", "admin", "kiosk"])
def test_token_store_roles_and_file(tmp_path: Any, role: str) -> None:
    store = TokenStore(tmp_path / "t.json")
    assert store.ensure_admin() is not None
    entry = store.create("Visitor desk", role)
    again = TokenStore(tmp_path / "t.json")
    assert again.identify(entry.token) == entry
    assert again.identify(entry.token + "x") is None
