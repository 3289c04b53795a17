"""Live Foxglove: a client speaking ``foxglove.sdk.v1`` subscribes to /scan and receives scans;
its teleop is refused until it presents the operator token, then goes through the safety
stage."""

from __future__ import annotations

import asyncio
import json
import struct
from typing import Any

import aiohttp
import pytest

from curio.app import App
from curio.core.clock import RealClock
from curio.core.config import Config
from curio.core.errors import SetupError
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, CMD_VEL_TELEOP

pytest.importorskip("foxglove", reason="the curio[foxglove] extra (foxglove-sdk) is missing")


class Client:
    """A minimal Foxglove WebSocket client (subprotocol foxglove.sdk.v1)."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.channels: dict[str, int] = {}
        self.statuses: list[str] = []
        self.data: list[tuple[int, bytes]] = []

    async def pump(self, until: Any, timeout_s: float = 20.0) -> None:  # loaded CI machines
        async def loop() -> None:
            while not until():
                msg = await self.ws.receive()
                if msg.type == aiohttp.WSMsgType.TEXT:
                    body = json.loads(msg.data)
                    if body["op"] == "advertise":
                        self.channels.update({c["topic"]: c["id"] for c in body["channels"]})
                    elif body["op"] == "status":
                        self.statuses.append(body["message"])
                elif msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == 1:
                    sub_id = struct.unpack_from("<I", msg.data, 1)[0]
                    self.data.append((sub_id, msg.data[13:]))
                else:
                    raise AssertionError(f"unexpected frame {msg.type}")
        await asyncio.wait_for(loop(), timeout_s)

    async def send(self, op: str, **body: Any) -> None:
        await self.ws.send_str(json.dumps({"op": op, **body}))

    async def publish(self, channel_id: int, payload: dict[str, Any]) -> None:
        await self.ws.send_bytes(struct.pack("<BI", 1, channel_id) + json.dumps(payload).encode())


async def test_scans_reach_a_client_and_teleop_needs_the_token(cfg: Config) -> None:
    cfg = cfg.model_copy(update={
        "foxglove": cfg.foxglove.model_copy(update={"enabled": True, "port": 0}),
        "record": cfg.record.model_copy(update={"enabled": False})})
    clock = RealClock()
    app = App(cfg, clock, web=False)
    assert app.recorder is not None
    port = app.recorder.sinks[0].port  # type: ignore[attr-defined]
    teleop: list[Twist] = []
    commanded: list[Twist] = []
    app.bus.add_tap(lambda topic, msg: (teleop if topic is CMD_VEL_TELEOP else commanded
                                        if topic is CMD_VEL else []).append(msg))
    await app.start()
    try:
        async with aiohttp.ClientSession() as session, session.ws_connect(
                f"ws://127.0.0.1:{port}/", protocols=["foxglove.sdk.v1"]) as ws:
            c = Client(ws)
            await c.pump(lambda: "/scan" in c.channels)
            await c.send("subscribe", subscriptions=[{"id": 5, "channelId": c.channels["/scan"]}])
            await c.pump(lambda: any(sub == 5 for sub, _ in c.data))
            scan = json.loads(next(d for sub, d in c.data if sub == 5))
            assert len(scan["ranges"]) == cfg.sim.lidar_beams and scan["frame_id"] == "laser"

            await c.send("advertise", channels=[{"id": 3, "topic": "/cmd_vel_teleop",
                                                 "encoding": "json",
                                                 "schemaName": "geometry_msgs/Twist"}])
            twist = {"linear": {"x": 0.2, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}}
            await c.publish(3, twist)
            await c.pump(lambda: bool(c.statuses))
            assert "operator_token" in c.statuses[0]
            await c.send("setParameters", parameters=[{"name": "operator_token",
                                                       "value": "wrong-token-123456"}])
            await c.publish(3, twist)
            await clock.sleep(0.3)
            assert not [t for t in teleop if t.source == "foxglove"]  # refused

            admin = app.tokens.first_admin()
            assert admin is not None
            token = admin.token
            await c.send("setParameters", parameters=[{"name": "operator_token",
                                                       "value": token}])
            for _ in range(15):  # hold the stick for 1.5 s
                await c.publish(3, twist)
                await clock.sleep(0.1)
        accepted = [t for t in teleop if t.source == "foxglove"]
        assert accepted and accepted[-1].linear_mps == pytest.approx(0.2)
        assert max(c.linear_mps for c in commanded) > 0.05  # through the safety stage
    finally:
        await app.stop()


def test_a_busy_port_is_a_setup_error(cfg: Config) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cfg = cfg.model_copy(update={"foxglove": cfg.foxglove.model_copy(
            update={"enabled": True, "port": port})})
        with pytest.raises(SetupError, match=f"foxglove.port = {port}"):
            App(cfg, RealClock(), web=False)
