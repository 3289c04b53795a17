"""The hardened server: security headers, the Host allow-list, strict JSON, waypoint indexes,
the map's bounds, caps on viewer sockets, odd tokens, tokens never in the log."""

from __future__ import annotations

import logging
from typing import Any

import aiohttp
import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage
from curio.core.topics import INITIAL_POSE, MAP, OPERATOR
from curio.web.services import GATE
from tests.web.conftest import ALICE, TOKEN, Dash, MakeDash, bearer


def publish_map(d: Dash) -> None:
    """A 10 m x 6 m map whose lower-left corner is at (-2, -1)."""
    data = np.zeros((120, 200), dtype=np.int8)
    d.bus.publish(MAP, GridMessage(0.0, data, 0.05, Pose2D(-2.0, -1.0, 0.0), version=1))


async def error_of(resp: aiohttp.ClientResponse, status: int) -> str:
    assert resp.status == status, await resp.text()
    assert resp.content_type == "application/json"
    body = await resp.json()
    assert body["status"] == status and "Traceback" not in body["error"]
    return str(body["error"])


async def test_security_headers_on_page_api_static_and_errors(make_dash: MakeDash) -> None:
    d = await make_dash()
    for path in ("/", "/api/state", "/static/app.js", "/api/nothing-here"):
        resp = await d.client.get(path)
        csp = resp.headers["Content-Security-Policy"]
        assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp, path
        assert resp.headers["X-Content-Type-Options"] == "nosniff"
        assert resp.headers["Referrer-Policy"] == "no-referrer"
        assert resp.headers["X-Frame-Options"] == "DENY"
    assert (await d.client.get("/api/state")).headers["Cache-Control"] == "no-store"


async def test_host_allow_list_refuses_rebound_names(make_dash: MakeDash) -> None:
    d = await make_dash()
    for host in ("127.0.0.1:8080", "localhost:8080", "192.168.4.1", "[::1]:8080"):
        assert (await d.client.get("/api/state", headers={"Host": host})).status == 200, host
    msg = await error_of(await d.client.get("/api/state", headers={"Host": "evil.example:80"}),
                         403)
    assert "evil.example" in msg and "web.allowed_hosts" in msg
    ws_resp = await d.client.get("/ws", headers={"Host": "attacker.test"})
    assert ws_resp.status == 403
    d.cfg.web.allowed_hosts = ["rover.example"]
    assert (await d.client.get("/", headers={"Host": "rover.example"})).status == 200


@pytest.mark.parametrize("body", [
    '{"action": "goto", "goal": {"x_m": 1' + "0" * 400 + ', "y_m": 0}}',
    '{"action": "goto", "goal": {"x_m": NaN, "y_m": 0}}',
    '{"action": "goto", "goal": {"x_m": Infinity, "y_m": 0}}',
    '{"action": "goto", "goal": {"x_m": 1e400, "y_m": 0}}',
    '{"action": "select_path", "path_id": 1' + "0" * 30 + '}',
    "[" * 100000 + "]" * 100000,
])
async def test_huge_or_odd_numbers_are_400_not_500(make_dash: MakeDash, body: str) -> None:
    d = await make_dash(max_message_bytes=300_000)
    ops = d.bus.subscribe(OPERATOR)
    resp = await d.client.post("/api/command", data=body, headers=d.auth)
    message = await error_of(resp, 400)
    assert "number" in message or "JSON" in message
    assert ops.drain() == []


async def test_huge_integers_everywhere(make_dash: MakeDash) -> None:
    d = await make_dash()
    publish_map(d)
    huge = "1" + "0" * 400
    for path, body in (
        ("/api/initial_pose", f'{{"x_m": {huge}, "y_m": 0, "yaw_rad": 0}}'),
        ("/api/paths/1/waypoints", f'{{"x_m": 0, "y_m": {huge}}}'),
        ("/api/paths", f'{{"name": "x", "waypoints": [{{"x_m": {huge}, "y_m": 0}}]}}'),
    ):
        await error_of(await d.client.post(path, data=body, headers=d.auth), 400)
    ws = await d.client.ws_connect(f"/ws?token={TOKEN}")
    await ws.send_str(f'{{"op": "teleop", "seq": 1, "linear_mps": {huge}}}')
    await ws.send_str('{"op": "teleop", "seq": 2, "linear_mps": 1e999}')
    errors = []
    while len(errors) < 2:
        msg = await ws.receive_json(timeout=5)
        if msg["t"] == "error":
            errors.append(msg)
    assert all(e["code"] == "rejected" and "number" in e["message"] for e in errors)
    await ws.close()


async def test_negative_and_out_of_range_waypoint_indexes(make_dash: MakeDash) -> None:
    d = await make_dash()
    before = [w.x_m for w in d.paths.get(1).waypoints]
    for index in ("-1", "-0x1", "1", "99", "one"):
        msg = await error_of(await d.client.delete(f"/api/paths/1/waypoints/{index}",
                                                   headers=d.auth), 400)
        assert "waypoint" in msg
    assert [w.x_m for w in d.paths.get(1).waypoints] == before
    resp = await d.client.patch("/api/paths/1/waypoints/-1", json={"x_m": 1, "y_m": 1},
                                headers=d.auth)
    await error_of(resp, 400)
    resp = await d.client.post("/api/paths/1/waypoints", json={"x_m": 1, "y_m": 1, "index": -1},
                               headers=d.auth)
    assert "0 to 1" in await error_of(resp, 400)


async def test_goals_waypoints_and_poses_off_the_map_are_refused(make_dash: MakeDash) -> None:
    d = await make_dash()
    publish_map(d)
    ops, poses = d.bus.subscribe(OPERATOR), d.bus.subscribe(INITIAL_POSE)
    bounds = "x from -2.00 to 8.00 m, y from -1.00 to 5.00 m"
    resp = await d.client.post("/api/command", headers=d.auth,
                               json={"action": "goto", "goal": {"x_m": 30.0, "y_m": 1.0}})
    assert bounds in await error_of(resp, 400)
    resp = await d.client.post("/api/paths/1/waypoints", json={"x_m": 1.0, "y_m": -3.0},
                               headers=d.auth)
    assert bounds in await error_of(resp, 400)
    resp = await d.client.post("/api/paths", headers=d.auth, json={
        "name": "x", "waypoints": [{"x_m": 1, "y_m": 1}, {"x_m": 9, "y_m": 1}]})
    assert "waypoint 1" in await error_of(resp, 400)
    resp = await d.client.post("/api/initial_pose", json={"x_m": -5, "y_m": 0, "yaw_rad": 0},
                               headers=d.auth)
    assert bounds in await error_of(resp, 400)
    ws = await d.client.ws_connect(f"/ws?token={TOKEN}")
    await ws.send_json({"op": "command", "id": 7, "action": "goto",
                        "goal": {"x_m": 0.0, "y_m": 99.0}})
    while (msg := await ws.receive_json(timeout=5))["t"] != "error":
        pass
    assert msg["id"] == 7 and bounds in msg["message"]
    await ws.close()
    assert ops.drain() == [] and poses.drain() == []
    assert [w.x_m for w in d.paths.get(1).waypoints] == [1.0]
    resp = await d.client.post("/api/command", headers=d.auth,
                               json={"action": "goto", "goal": {"x_m": 7.9, "y_m": 4.9}})
    assert resp.status == 202


async def test_viewer_sockets_are_capped_per_address_and_in_total(make_dash: MakeDash) -> None:
    d = await make_dash(max_viewer_sockets_per_ip=3, max_viewer_sockets=4)
    viewers = [await d.client.ws_connect("/ws") for _ in range(3)]
    with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
        await d.client.ws_connect("/ws")
    assert refused.value.status == 503
    operator = await d.client.ws_connect(f"/ws?token={ALICE}")  # tokens are not capped
    hello = await operator.receive_json(timeout=5)
    assert hello["who"]["name"] == "alice"
    await viewers.pop().close()
    for _ in range(100):
        if sum(d.client.app[GATE].viewer_sockets.values()) < 3:
            break
        await d.clock.sleep(0)
    viewers.append(await d.client.ws_connect("/ws"))
    await operator.close()
    for ws in viewers:
        await ws.close()


async def test_odd_tokens_get_a_plain_403(make_dash: MakeDash) -> None:
    d = await make_dash()
    for headers in ({"Authorization": "Bearer tökén-ünïcode-ääääääää"},
                    {"X-Curio-Token": "t\u00f6ken"}):
        resp = await d.client.post("/api/command", json={"action": "go_home"}, headers=headers)
        assert "token is wrong" in await error_of(resp, 403)
    resp = await d.client.post("/api/command?token=%E2%98%83", json={"action": "go_home"})
    assert "other characters" in await error_of(resp, 403)
    raw = {"Authorization": b"Bearer \xff\xfe-raw-bytes".decode("latin-1")}
    resp = await d.client.post("/api/command", json={"action": "go_home"}, headers=raw)
    await error_of(resp, 403)


async def test_wrong_token_bursts_are_throttled_and_logged_once(
        make_dash: MakeDash, caplog: pytest.LogCaptureFixture) -> None:
    d = await make_dash(wrong_token_limit=5, wrong_token_window_s=60.0)
    caplog.set_level(logging.WARNING, logger="curio.web.auth")
    statuses = []
    for i in range(20):
        resp = await d.client.post("/api/command", json={"action": "go_home"},
                                   headers=bearer(f"guess-{i:04d}-aaaaaaaaaaaaaaaa"))
        statuses.append(resp.status)
    assert statuses == [403] * 4 + [403] + [429] * 15
    throttles = [r for r in caplog.records if "refused for" in r.getMessage()]
    assert len(throttles) == 1
    assert sum("wrong token from" in r.getMessage() for r in caplog.records) == 4
    # A right token from the throttled address: an e-stop still gets through ...
    resp = await d.client.post("/api/estop", headers=bearer(ALICE))
    assert resp.status == 202
    # ... anything else waits out the throttle.
    resp = await d.client.post("/api/command", json={"action": "go_home"}, headers=bearer(ALICE))
    assert resp.status == 429 and "Retry-After" in resp.headers
    await d.clock.advance(61.0)
    resp = await d.client.post("/api/command", json={"action": "go_home"}, headers=bearer(ALICE))
    assert resp.status == 202


async def test_tokens_never_reach_the_log(make_dash: MakeDash,
                                          caplog: pytest.LogCaptureFixture) -> None:
    d = await make_dash()
    caplog.set_level(logging.DEBUG)
    secret_wrong = "wrong-secret-zzzzzzzzzzzzzzzzzz"
    attempts: list[dict[str, Any]] = [
        {"protocols": (f"curio.token.{TOKEN}",)},  # the subprotocol alone: aiohttp logs it
        {"protocols": ("curio.v1", f"curio.token.{ALICE}")},
        {"protocols": (f"curio.token.{secret_wrong}",)},
    ]
    for kwargs in attempts:
        try:
            ws = await d.client.ws_connect("/ws", **kwargs)
            await ws.receive_json(timeout=5)
            await ws.close()
        except aiohttp.WSServerHandshakeError:
            pass
    await d.client.post(f"/api/command?token={secret_wrong}", json={"action": "go_home"})
    await d.client.post("/api/command", json={"action": "go_home"}, headers=bearer(TOKEN))
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "Client protocols" in text  # aiohttp did log the refused subprotocol ...
    for secret in (TOKEN, ALICE, secret_wrong):
        assert secret not in text  # ... without the token
