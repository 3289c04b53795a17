"""REST API of the dashboard: auth, validation, paths, grids, limits (aiohttp test client)."""

from __future__ import annotations

import asyncio
import io
import json

import numpy as np
from PIL import Image

from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage
from curio.core.topics import INITIAL_POSE, MAP, OPERATOR
from tests.web.conftest import TOKEN, MakeDash


async def settle() -> None:
    for _ in range(5):
        await asyncio.sleep(0)  # noqa: TID251 - let the hub's pump tasks run


async def test_page_is_served_without_cdn(make_dash: MakeDash) -> None:
    d = await make_dash()
    resp = await d.client.get("/")
    assert resp.status == 200
    html = await resp.text()
    assert "Go Home" in html and "/static/app.js?v=" in html
    assert "http://" not in html and "https://" not in html  # nothing fetched from outside
    js = await d.client.get("/static/app.js")
    assert js.status == 200
    assert "cdn" not in (await js.text()).lower()


async def test_viewing_is_open_control_needs_the_token(make_dash: MakeDash) -> None:
    d = await make_dash()
    state = await (await d.client.get("/api/state")).json()
    assert state["control"] is False
    assert [p["id"] for p in state["paths"]] == [0, 1, 2, 3, 4]
    state = await (await d.client.get("/api/state", headers=d.auth)).json()
    assert state["control"] is True

    sub = d.bus.subscribe(OPERATOR)
    resp = await d.client.post("/api/command", json={"action": "go_home"})
    assert resp.status == 401
    body = await resp.json()
    assert "token" in body["error"] and body["status"] == 401
    resp = await d.client.post("/api/command", json={"action": "go_home"},
                               headers={"Authorization": "Bearer wrong-token-xxxxxxxx"})
    assert resp.status == 403
    assert "wrong" in (await resp.json())["error"]
    assert sub.drain() == []

    resp = await d.client.post("/api/command", json={"action": "go_home"}, headers=d.auth)
    assert resp.status == 202
    cmds = sub.drain()
    assert [c.action for c in cmds] == ["go_home"]
    assert cmds[0].source == "web:admin"  # the token names who sent it
    # The token also works as a query parameter (the start-up URL) and as X-Curio-Token.
    resp = await d.client.post(f"/api/command?token={TOKEN}", json={"action": "pause"})
    assert resp.status == 202
    resp = await d.client.post("/api/command", json={"action": "resume"},
                               headers={"X-Curio-Token": TOKEN})
    assert resp.status == 202
    assert [c.action for c in sub.drain()] == ["pause", "resume"]


async def test_bad_path_number_says_which_paths_exist(make_dash: MakeDash) -> None:
    d = await make_dash()
    sub = d.bus.subscribe(OPERATOR)
    resp = await d.client.post("/api/command", json={"action": "select_path", "path_id": 7},
                               headers=d.auth)
    assert resp.status == 400
    assert (await resp.json())["error"] == "There is no path 7; paths are 0–4"
    resp = await d.client.post("/api/command", json={"action": "select_path", "path_id": "abc"},
                               headers=d.auth)
    assert resp.status == 400
    assert "whole number" in (await resp.json())["error"]
    resp = await d.client.post("/api/command", json={"action": "select_path"}, headers=d.auth)
    assert "path_id" in (await resp.json())["error"]
    assert sub.drain() == []
    resp = await d.client.post("/api/command", json={"action": "select_path", "path_id": "2"},
                               headers=d.auth)
    assert resp.status == 202
    assert [(c.action, c.path_id) for c in sub.drain()] == [("select_path", 2)]


async def test_malformed_and_unknown_commands_are_rejected_with_reasons(
    make_dash: MakeDash,
) -> None:
    d = await make_dash()
    sub = d.bus.subscribe(OPERATOR)
    resp = await d.client.post("/api/command", data=b"{not json", headers=d.auth)
    assert resp.status == 400
    assert "not valid JSON" in (await resp.json())["error"]
    resp = await d.client.post("/api/command", data=b"[1, 2]", headers=d.auth)
    assert "JSON object" in (await resp.json())["error"]
    resp = await d.client.post("/api/command", json={"action": "fly"}, headers=d.auth)
    error = (await resp.json())["error"]
    assert "unknown action 'fly'" in error and "go_home" in error
    resp = await d.client.post("/api/command", json={"action": "goto", "goal": {"x_m": 1}},
                               headers=d.auth)
    assert "'y_m' is required" in (await resp.json())["error"]
    resp = await d.client.post("/api/command",
                               json={"action": "goto", "goal": {"x_m": 1, "y_m": "north"}},
                               headers=d.auth)
    assert "finite number" in (await resp.json())["error"]
    assert sub.drain() == []
    resp = await d.client.post("/api/command",
                               json={"action": "goto", "goal": {"x_m": 1.5, "y_m": -2}},
                               headers=d.auth)
    assert resp.status == 202
    (cmd,) = sub.drain()
    assert cmd.goal == Pose2D(1.5, -2.0, 0.0)


async def test_oversized_request_is_rejected(make_dash: MakeDash) -> None:
    d = await make_dash(max_message_bytes=1024)
    resp = await d.client.post("/api/command", data=b'{"action": "pause", "x": "' + b"a" * 4000
                               + b'"}', headers={**d.auth, "Content-Type": "application/json"})
    assert resp.status == 413
    assert "max_message_bytes=1024" in (await resp.json())["error"]


async def test_control_requests_are_rate_limited(make_dash: MakeDash) -> None:
    d = await make_dash(max_messages_per_s=5.0)
    statuses = []
    for _ in range(8):
        resp = await d.client.post("/api/command", json={"action": "pause"}, headers=d.auth)
        statuses.append(resp.status)
    assert statuses[:5] == [202] * 5
    assert statuses[5:] == [429] * 3
    resp = await d.client.post("/api/command", json={"action": "pause"}, headers=d.auth)
    assert "at most 5 per second" in (await resp.json())["error"]
    await d.clock.advance(1.0)  # the bucket refills with (simulated) time
    resp = await d.client.post("/api/command", json={"action": "pause"}, headers=d.auth)
    assert resp.status == 202


async def test_duplicate_request_id_is_not_published_twice(make_dash: MakeDash) -> None:
    d = await make_dash()
    sub = d.bus.subscribe(OPERATOR)
    body = {"action": "go_home", "request_id": "web-abc-1"}
    first = await (await d.client.post("/api/command", json=body, headers=d.auth)).json()
    second = await (await d.client.post("/api/command", json=body, headers=d.auth)).json()
    assert first["duplicate"] is False and second["duplicate"] is True
    assert len(sub.drain()) == 1


async def test_foreign_origin_cannot_control(make_dash: MakeDash) -> None:
    d = await make_dash()
    resp = await d.client.post("/api/command", json={"action": "go_home"},
                               headers={**d.auth, "Origin": "http://evil.example"})
    assert resp.status == 403
    assert "evil.example" in (await resp.json())["error"]
    host = f"{d.client.host}:{d.client.port}"
    resp = await d.client.post("/api/command", json={"action": "go_home"},
                               headers={**d.auth, "Origin": f"http://{host}"})
    assert resp.status == 202


async def test_allowed_origins_config(make_dash: MakeDash) -> None:
    d = await make_dash(allowed_origins=["http://tablet.local:8080"])
    resp = await d.client.post("/api/command", json={"action": "go_home"},
                               headers={**d.auth, "Origin": "http://tablet.local:8080"})
    assert resp.status == 202


async def test_path_editor_endpoints(make_dash: MakeDash) -> None:
    d = await make_dash()
    resp = await d.client.post("/api/paths", json={"name": "Lab"})
    assert resp.status == 401
    resp = await d.client.post("/api/paths", json={"name": "Lab"}, headers=d.auth)
    assert resp.status == 201
    created = await resp.json()
    pid = created["id"]
    assert {k: v for k, v in created.items() if k != "rev"} == \
        {"id": 5, "name": "Lab", "waypoints": []}
    for x in (1.0, 2.0):
        resp = await d.client.post(f"/api/paths/{pid}/waypoints", json={"x_m": x, "y_m": 0.5},
                                   headers=d.auth)
        assert resp.status == 201
    resp = await d.client.post(f"/api/paths/{pid}/waypoints",
                               json={"x_m": 3, "y_m": 1, "yaw_rad": 1.0}, headers=d.auth)
    assert (await resp.json())["waypoints"][-1] == {"x_m": 3.0, "y_m": 1.0, "yaw_rad": 1.0}
    assert [(w.x_m, w.y_m) for w in d.paths.get(pid).waypoints] == [(1, .5), (2, .5), (3, 1)]
    resp = await d.client.delete(f"/api/paths/{pid}/waypoints/1", headers=d.auth)
    assert [w["x_m"] for w in (await resp.json())["waypoints"]] == [1.0, 3.0]
    resp = await d.client.patch(f"/api/paths/{pid}", json={"name": "Lab tour"}, headers=d.auth)
    assert (await resp.json())["name"] == "Lab tour"
    # The path manager's own refusals reach the operator as 400 with its message.
    resp = await d.client.patch(f"/api/paths/{pid}", json={"name": "  "}, headers=d.auth)
    assert resp.status == 400
    assert (await resp.json())["error"] == "A path needs a name."
    resp = await d.client.delete("/api/paths/0", headers=d.auth)
    assert resp.status == 400 and "cannot be deleted" in (await resp.json())["error"]
    resp = await d.client.post("/api/paths/9/waypoints", json={"x_m": 0, "y_m": 0},
                               headers=d.auth)
    assert resp.status == 404
    assert (await resp.json())["error"] == "There is no path 9; paths are 0–5"
    resp = await d.client.post(f"/api/paths/{pid}/waypoints", json={"x_m": "a", "y_m": 0},
                               headers=d.auth)
    assert resp.status == 400 and "'x_m' must be a finite number" in (await resp.json())["error"]
    resp = await d.client.delete(f"/api/paths/{pid}", headers=d.auth)
    assert resp.status == 200
    assert [p["id"] for p in await (await d.client.get("/api/paths")).json()] == [0, 1, 2, 3, 4]


async def test_map_png_is_versioned_and_oriented(make_dash: MakeDash) -> None:
    d = await make_dash()
    resp = await d.client.get("/api/map.png")
    assert resp.status == 404
    assert "no map" in (await resp.json())["error"]
    data = np.zeros((4, 6), dtype=np.int8)
    data[0, 0] = 100  # bottom-left cell occupied
    data[3, 5] = -1  # top-right unknown
    grid = GridMessage(0.0, data, 0.05, Pose2D(-1.0, -2.0, 0.0), version=3)
    d.bus.publish(MAP, grid)
    await settle()
    meta = await (await d.client.get("/api/map.json")).json()
    assert meta["width"] == 6 and meta["height"] == 4 and meta["origin"] == [-1.0, -2.0, 0.0]
    version = meta["version"]
    resp = await d.client.get(f"/api/map.png?v={version}")
    assert resp.status == 200 and resp.content_type == "image/png"
    assert "immutable" in resp.headers["Cache-Control"]
    img = np.asarray(Image.open(io.BytesIO(await resp.read())).convert("RGBA"))
    assert img.shape == (4, 6, 4)
    assert tuple(img[3, 0, :3]) == (0, 0, 0)  # bottom row of the image = row 0 of the grid
    assert tuple(img[0, 5, :3]) == (205, 205, 205)  # unknown grey
    assert tuple(img[1, 1, :3]) == (254, 254, 254)  # free white
    # Same version again: no new version; new content: a new version.
    d.bus.publish(MAP, GridMessage(1.0, data, 0.05, Pose2D(-1.0, -2.0, 0.0), version=3))
    await settle()
    assert (await (await d.client.get("/api/map.json")).json())["version"] == version
    d.bus.publish(MAP, GridMessage(2.0, data, 0.05, Pose2D(-1.0, -2.0, 0.0), version=4))
    await settle()
    assert (await (await d.client.get("/api/map.json")).json())["version"] > version


async def test_initial_pose_is_published(make_dash: MakeDash) -> None:
    d = await make_dash()
    sub = d.bus.subscribe(INITIAL_POSE)
    resp = await d.client.post("/api/initial_pose", json={"x_m": 1.0, "y_m": 2.0, "yaw_rad": 0.5},
                               headers=d.auth)
    assert resp.status == 202
    (msg,) = sub.drain()
    assert msg.pose == Pose2D(1.0, 2.0, 0.5) and msg.frame_id == "map"


async def test_unknown_routes_and_methods_answer_json(make_dash: MakeDash) -> None:
    d = await make_dash()
    resp = await d.client.get("/api/nothing")
    assert resp.status == 404
    assert "/api/nothing" in (await resp.json())["error"]
    resp = await d.client.put("/api/command", data=json.dumps({}), headers=d.auth)
    assert resp.status == 405
    assert "PUT" in (await resp.json())["error"]
