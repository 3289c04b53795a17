"""WebSocket hub: snapshots, binary frames, rate limits, teleop safety, slow clients."""

from __future__ import annotations

import asyncio
import json
import math
from typing import Any

import aiohttp
import numpy as np
import pytest
from aiohttp import WSMsgType

from curio.core.geometry import Pose2D
from curio.core.messages import (
    DriverHealth,
    Event,
    LaserScan,
    Path,
    PoseWithCovariance,
    Progress,
    StatusText,
    TreeSnapshot,
)
from curio.core.topics import (
    CMD_VEL_TELEOP,
    EVENTS,
    HEALTH,
    OPERATOR,
    PLAN,
    POSE,
    PROGRESS,
    SCAN,
    STATUS,
    TREE,
)
from curio.web import hub as hub_module
from curio.web.encode import FRAME_PLAN, FRAME_POSE, FRAME_SCAN, decode_frame
from curio.web.tokens import VIEWER
from tests.web.conftest import TOKEN, Dash, MakeDash, recv_json_until

WsMsg = aiohttp.WSMessage




async def connect(d: Dash, token: bool = True) -> aiohttp.ClientWebSocketResponse:
    ws = await d.client.ws_connect(f"/ws?token={TOKEN}" if token else "/ws")
    hello = await recv_json_until(ws, lambda m: m["t"] == "hello")
    assert hello["control"] is token
    await recv_json_until(ws, lambda m: m["t"] == "state")
    return ws


async def spin(n: int = 10) -> None:
    for _ in range(n):
        await asyncio.sleep(0)  # noqa: TID251 - let the hub's tasks run


async def test_viewer_cannot_control(make_dash: MakeDash) -> None:
    d = await make_dash()
    teleop = d.bus.subscribe(CMD_VEL_TELEOP)
    ops = d.bus.subscribe(OPERATOR)
    ws = await connect(d, token=False)
    await ws.send_json({"op": "teleop", "linear_mps": 0.2, "angular_radps": 0.0, "id": 1})
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert err["id"] == 1 and "viewing only" in err["message"]
    await ws.send_json({"op": "command", "action": "go_home"})
    await recv_json_until(ws, lambda m: m["t"] == "error")
    assert teleop.drain() == [] and ops.drain() == []
    await ws.close()


async def test_wrong_token_and_foreign_origin_are_refused(make_dash: MakeDash) -> None:
    d = await make_dash()
    with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
        await d.client.ws_connect("/ws?token=not-the-token-at-all")
    assert exc.value.status == 403
    with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
        await d.client.ws_connect("/ws", headers={"Origin": "http://evil.example"})
    assert exc.value.status == 403
    resp = await d.client.get("/ws", headers={"Origin": "http://evil.example",
                                              "Upgrade": "websocket", "Connection": "Upgrade"})
    assert "evil.example" in (await resp.json())["error"]


async def test_commands_over_the_socket_are_acknowledged_once(make_dash: MakeDash) -> None:
    d = await make_dash()
    ops = d.bus.subscribe(OPERATOR)
    ws = await connect(d)
    await ws.send_json({"op": "command", "id": 7, "action": "select_path", "path_id": 2,
                        "request_id": "r-1"})
    ack = await recv_json_until(ws, lambda m: m["t"] == "ack")
    assert ack == {"t": "ack", "id": 7, "request_id": "r-1", "action": "select_path",
                   "duplicate": False}
    await ws.send_json({"op": "command", "id": 8, "action": "select_path", "path_id": 2,
                        "request_id": "r-1"})
    ack = await recv_json_until(ws, lambda m: m["t"] == "ack")
    assert ack["duplicate"] is True
    await ws.send_json({"op": "command", "id": 9, "action": "select_path", "path_id": 7})
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert err["id"] == 9 and err["message"] == "There is no path 7; paths are 0–4"
    assert [(c.action, c.path_id) for c in ops.drain()] == [("select_path", 2)]
    await ws.close()


async def test_malformed_messages_get_an_error_and_the_socket_stays(make_dash: MakeDash) -> None:
    d = await make_dash()
    ws = await connect(d)
    await ws.send_str("{oops")
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert "not valid JSON" in err["message"]
    await ws.send_str("[1]")
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert "JSON object" in err["message"]
    await ws.send_json({"op": "dance"})
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert "unknown op 'dance'" in err["message"] and "teleop" in err["message"]
    await ws.send_json({"op": "teleop", "linear_mps": "fast"})
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert "finite number" in err["message"]
    await ws.send_bytes(b"\x00\x01")
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert "binary" in err["message"]
    await ws.send_json({"op": "ping", "id": "p"})
    assert (await recv_json_until(ws, lambda m: m["t"] == "pong"))["id"] == "p"
    await ws.close()


async def test_oversized_message_closes_with_1009(make_dash: MakeDash) -> None:
    d = await make_dash(max_message_bytes=1024)
    ws = await connect(d)
    await ws.send_str(json.dumps({"op": "ping", "pad": "x" * 2000}))
    err = await recv_json_until(ws, lambda m: m["t"] == "error")
    assert err["code"] == "too_big" and "max_message_bytes=1024" in err["message"]
    msg = await ws.receive(timeout=5.0)
    assert msg.type == WSMsgType.CLOSE and msg.data == 1009


async def test_message_rate_limit(make_dash: MakeDash) -> None:
    d = await make_dash(max_messages_per_s=10.0)
    ws = await connect(d)
    for i in range(30):
        await ws.send_json({"op": "ping", "id": i})
    pongs: list[int] = []
    errors: list[dict[str, Any]] = []
    while len(pongs) + len(errors) < 11:
        data = await recv_json_until(ws, lambda m: m["t"] in ("pong", "error"))
        (pongs.append(data["id"]) if data["t"] == "pong" else errors.append(data))
    assert pongs == list(range(10))  # the burst, then nothing until time passes
    assert len(errors) == 1 and errors[0]["code"] == "rate_limited"
    assert "at most 10 per second" in errors[0]["message"]
    await d.clock.advance(1.0)
    await ws.send_json({"op": "ping", "id": "later"})
    assert (await recv_json_until(ws, lambda m: m["t"] == "pong"))["id"] == "later"
    await ws.close()


async def test_teleop_publishes_and_disconnect_stops_the_rover(make_dash: MakeDash) -> None:
    d = await make_dash()
    teleop = d.bus.subscribe(CMD_VEL_TELEOP, maxsize=100)
    ws = await connect(d)
    await ws.send_json({"op": "teleop", "seq": 1, "linear_mps": 0.2, "angular_radps": -0.5})
    await ws.send_json({"op": "teleop", "seq": 2, "linear_mps": 5.0, "angular_radps": 0.0})
    await ws.send_json({"op": "teleop", "seq": 1, "linear_mps": 0.3, "angular_radps": 0.0})
    await ws.send_json({"op": "ping"})
    await recv_json_until(ws, lambda m: m["t"] == "pong")
    msgs = teleop.drain()
    limit = min(d.cfg.robot.max_wheel_speed_mps, d.cfg.nav.safety.max_speed_mps)
    assert [(m.linear_mps, m.angular_radps) for m in msgs] == [(0.2, -0.5), (limit, 0.0)]
    assert all(m.source == "web:admin" for m in msgs)  # the token names the driver
    await ws.close()
    for _ in range(100):
        await spin()
        if len(teleop):
            break
    (stop,) = teleop.drain()
    assert (stop.linear_mps, stop.angular_radps) == (0.0, 0.0)


async def test_teleop_watchdog_stops_a_silent_client(make_dash: MakeDash) -> None:
    d = await make_dash()
    teleop = d.bus.subscribe(CMD_VEL_TELEOP, maxsize=100)
    ws = await connect(d)
    await ws.send_json({"op": "teleop", "seq": 1, "linear_mps": 0.2, "angular_radps": 0.0})
    await ws.send_json({"op": "ping"})
    await recv_json_until(ws, lambda m: m["t"] == "pong")
    assert [m.linear_mps for m in teleop.drain()] == [0.2]
    await d.clock.advance(0.3)
    assert teleop.drain() == []  # still within the timeout
    await d.clock.advance(0.4)
    (stop,) = teleop.drain()
    assert stop.linear_mps == 0.0 and stop.stamp <= 0.7
    await d.clock.advance(1.0)
    assert teleop.drain() == []  # one stop, not a stream of them
    await ws.close()


async def test_reconnecting_client_gets_state_and_no_command_replay(make_dash: MakeDash) -> None:
    d = await make_dash()
    ops = d.bus.subscribe(OPERATOR)
    ws = await connect(d)
    await ws.send_json({"op": "command", "id": 1, "action": "pause"})
    await recv_json_until(ws, lambda m: m["t"] == "ack")
    d.bus.publish(STATUS, StatusText(1.0, "Moving to (1,0)", "moving"))
    d.bus.publish(PROGRESS, Progress(1.0, 1, "Path 1", ("reached", "active", "pending"), 1))
    d.bus.publish(EVENTS, Event(2.0, "help.requested", {"message": "the door is blocked"}))
    d.bus.publish(STATUS, StatusText(2.0, "HELP ME!", "needs_help"))
    status = await recv_json_until(ws, lambda m: m["t"] == "status" and
                                   m["status"]["state"] == "needs_help")
    assert status["help"]["active"] is True
    await ws.close()

    ws2 = await d.client.ws_connect(f"/ws?token={TOKEN}")
    state = await recv_json_until(ws2, lambda m: m["t"] == "state")
    assert state["status"]["text"] == "HELP ME!"
    assert state["progress"]["states"] == ["reached", "active", "pending"]
    assert state["help"]["active"] is True and state["help"]["message"] == "the door is blocked"
    assert [e["kind"] for e in state["events"]] == ["operator.command", "help.requested"]
    assert state["events"][0]["detail"]["who"] == "admin"  # who did what
    await spin(50)
    assert [c.action for c in ops.drain()] == ["pause"]  # published once, never replayed
    d.bus.publish(EVENTS, Event(3.0, "help.resolved", {}))
    ev = await recv_json_until(ws2, lambda m: m["t"] == "event")
    assert ev["event"]["kind"] == "help.resolved" and ev["help"]["active"] is False
    await ws2.close()


def _scan(stamp: float) -> LaserScan:
    ranges = np.array([1.0, np.inf, np.nan, 2.5, 0.0], dtype=np.float32)
    return LaserScan(stamp, -0.5, 0.25, 0.15, 12.0, ranges)


async def test_binary_frames_for_scan_pose_and_plan(make_dash: MakeDash) -> None:
    d = await make_dash()
    d.bus.publish(POSE, PoseWithCovariance(0.5, Pose2D(1.0, 2.0, math.pi / 2)))
    d.bus.publish(SCAN, _scan(0.6))
    d.bus.publish(PLAN, Path(0.7, (Pose2D(0, 0), Pose2D(1, 0.5))))
    await spin()
    ws = await connect(d)  # latched frames arrive with the snapshot
    frames: dict[int, dict[str, Any]] = {}
    while len(frames) < 3:
        msg = await ws.receive(timeout=5.0)
        if msg.type == WSMsgType.BINARY:
            f = decode_frame(msg.data)
            frames[f["type"]] = f
    pose = frames[FRAME_POSE]
    assert (pose["x"], pose["y"]) == (1.0, 2.0)
    assert pose["std"][0] == pytest.approx(0.5)
    scan = frames[FRAME_SCAN]
    assert scan["ranges_mm"] == [1000, 0, 0, 2500, 0]
    lx, ly, lyaw = scan["laser"]  # laser mount (0.152, 0.078) rotated by 90°
    assert lx == pytest.approx(1.0 - 0.078, abs=1e-5)
    assert ly == pytest.approx(2.0 + 0.152, abs=1e-5)
    assert lyaw == pytest.approx(math.pi / 2, abs=1e-6)
    assert frames[FRAME_PLAN]["points"] == [[0.0, 0.0], [1.0, 0.5]]
    await ws.close()


async def test_streams_are_rate_limited_per_client(make_dash: MakeDash) -> None:
    d = await make_dash(client_rate_hz=5.0)
    ws = await connect(d)
    received = 0

    async def reader() -> None:
        nonlocal received
        async for msg in ws:
            if msg.type == WSMsgType.BINARY and decode_frame(msg.data)["type"] == FRAME_POSE:
                received += 1

    task = asyncio.create_task(reader())
    for i in range(100):  # 2 s of poses at 50 Hz
        d.bus.publish(POSE, PoseWithCovariance(i * 0.02, Pose2D(i * 0.01, 0.0, 0.0)))
        await spin()
        await d.clock.advance(0.02)
        await spin()
    await ws.close()
    await task
    assert 8 <= received <= 12, received  # 5 Hz over 2 s, not 50 Hz


async def test_tree_snapshot_is_forwarded(make_dash: MakeDash) -> None:
    d = await make_dash()
    ws = await connect(d)
    nodes = ({"id": "1", "name": "Root", "type": "Selector", "status": "RUNNING",
              "parent": None, "children": ["2"]},
             {"id": "2", "name": "Pause?", "type": "Condition", "status": "FAILURE",
              "parent": "1", "children": []})
    d.bus.publish(TREE, TreeSnapshot(1.0, 4, nodes, {"paused": False, "path": 1}))
    tree = await recv_json_until(ws, lambda m: m["t"] == "tree")
    assert tree["tree"]["tick"] == 4
    assert [n["name"] for n in tree["tree"]["nodes"]] == ["Root", "Pause?"]
    assert tree["tree"]["blackboard"] == {"paused": False, "path": 1}
    resp = await d.client.get("/api/tree")
    assert (await resp.json())["nodes"][1]["status"] == "FAILURE"
    await ws.close()


class _StalledSocket:
    """A client whose network never drains: every send waits for ever."""

    closed = False

    def __init__(self) -> None:
        self.never: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.close_code: int | None = None

    async def send_str(self, _data: str) -> None:
        await self.never

    async def send_bytes(self, _data: bytes) -> None:
        await self.never

    async def close(self, code: int = 1000, message: bytes = b"") -> None:
        self.close_code = code
        self.closed = True


async def test_slow_client_is_dropped_without_stalling_others(
    make_dash: MakeDash, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(hub_module, "MAX_BACKLOG", 20)
    d = await make_dash()
    ws = await connect(d)
    stalled = _StalledSocket()
    slow = d.hub.register(stalled, VIEWER)  # type: ignore[arg-type]
    sender = asyncio.ensure_future(slow.send_loop())
    await spin()
    for i in range(40):  # the healthy client keeps up, the stalled one cannot
        d.bus.publish(STATUS, StatusText(float(i), f"status {i}", "moving"))
        await spin(3)
    last = await recv_json_until(ws, lambda m: m["t"] == "status" and
                                 m["status"]["text"] == "status 39")
    assert last["status"]["state"] == "moving"
    await spin()
    assert slow not in d.hub.clients
    assert stalled.close_code == 1013
    sender.cancel()
    await ws.close()


async def test_help_state_clears_when_the_tree_moves_on(make_dash: MakeDash) -> None:
    d = await make_dash()
    ws = await connect(d)
    d.bus.publish(STATUS, StatusText(1.0, "Needs help", "needs_help"))
    msg = await recv_json_until(ws, lambda m: m["t"] == "status")
    assert msg["help"]["active"] is True
    d.bus.publish(STATUS, StatusText(2.0, "Paused", "paused"))  # still waiting
    msg = await recv_json_until(ws, lambda m: m["t"] == "status")
    assert msg["help"]["active"] is True
    d.bus.publish(STATUS, StatusText(3.0, "Going home", "going_home"))
    msg = await recv_json_until(ws, lambda m: m["t"] == "status")
    assert msg["help"]["active"] is False
    await ws.close()


async def test_health_panel_has_components_system_and_bus(make_dash: MakeDash) -> None:
    d = await make_dash()
    d.bus.publish(HEALTH, DriverHealth(0.5, "lidar", "degraded", "3 bad packets",
                                       {"bad_packets": 3.0}))
    web_health = d.bus.subscribe(HEALTH, maxsize=10)
    ws = await connect(d)
    await d.clock.advance(1.05)
    health = await recv_json_until(ws, lambda m: m["t"] == "health")
    lidar = next(c for c in health["components"] if c["name"] == "lidar")
    assert [(c["key"], c["value"]) for c in lidar["counters"]] == [("bad_packets", 3.0)]
    assert lidar["state"] == "degraded" and lidar["message"] == "3 bad packets"
    assert lidar["age_s"] == pytest.approx(0.5, abs=0.06)  # reported at 0.5, panel at 1.0
    assert "loop_lag_ms" in health["system"] and health["system"]["cpu_count"] >= 1
    assert health["bus"]["dropped_total"] >= 0
    own = [h for h in web_health.drain() if h.name == "web"]
    assert own and own[0].counters["clients"] == 1.0
    await ws.close()


async def test_a_single_goal_clears_the_old_paths_squares(make_dash: MakeDash) -> None:
    d = await make_dash()
    ws = await connect(d)
    d.bus.publish(PROGRESS, Progress(1.0, 1, "Path 1", ("reached", "reached"), 1))
    msg = await recv_json_until(ws, lambda m: m["t"] == "progress")
    assert msg["progress"]["path_id"] == 1
    d.bus.publish(EVENTS, Event(2.0, "nav.goal_accepted", {
        "goal_id": 7, "goal": [[2.0, 0.0]], "tag": "web:admin goto"}))
    goal = await recv_json_until(ws, lambda m: m["t"] == "goal")
    assert goal["goal"]["poses"] == [[2.0, 0.0]]
    msg = await recv_json_until(ws, lambda m: m["t"] == "progress")
    assert msg["progress"] is None and d.hub.snapshot()["progress"] is None
    d.bus.publish(EVENTS, Event(3.0, "nav.goal_canceled", {"goal_id": 7}))
    goal = await recv_json_until(ws, lambda m: m["t"] == "goal")
    assert goal["goal"] is None
    await ws.close()
