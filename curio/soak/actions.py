"""What a soak client does, one function per action (:func:`perform` picks by name).

Valid commands expect the rover's answer (``bt.command_accepted`` / ``rejected``); invalid
ones expect the dashboard to refuse them with a reason. Path edits go over REST on the
client's scratch path and are tracked in its :class:`~curio.soak.clients.PathEdits`.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import aiohttp

if TYPE_CHECKING:  # pragma: no cover
    from curio.soak.clients import SoakClient

__all__ = ["perform"]

INVALID: list[dict[str, Any]] = [
    {"action": "fly"},
    {"action": "goto", "goal": {"x_m": 500.0, "y_m": 3.0}},
    {"action": "goto"},
    {"action": "select_path", "path_id": 99},
    {"action": "select_path", "path_id": "abc"},
    {"action": "select_path"},
    {"action": "goto", "goal": {"x_m": "NaN", "y_m": 1.0}},
]


async def _pause_resume(c: SoakClient) -> None:
    from curio.soak.clients import WALL

    await c.command("pause")
    await WALL.sleep(float(c.rng.uniform(0.5, 4.0)))
    await c.command("resume")


async def _estop_release(c: SoakClient) -> None:
    from curio.soak.clients import WALL

    await c.command("estop")
    await WALL.sleep(float(c.rng.uniform(0.5, 5.0)))
    await c.command("release_estop")


async def _goto(c: SoakClient) -> None:
    from curio.soak.clients import GOOD_POINTS

    x, y = GOOD_POINTS[int(c.rng.integers(len(GOOD_POINTS)))]
    await c.command("goto", goal={"x_m": x, "y_m": y})


async def _teleop(c: SoakClient) -> None:
    from curio.soak.clients import WALL

    lin = float(c.rng.uniform(-0.15, 0.25))
    ang = float(c.rng.uniform(-0.6, 0.6))
    for k in range(int(c.rng.integers(3, 10))):
        await c._send({"op": "teleop", "id": f"t{c.spec.index}-{c.seq}-{k}", "seq": c.seq * 100
                       + k, "linear_mps": lin, "angular_radps": ang})
        await WALL.sleep(0.15)
    await c._send({"op": "teleop", "id": f"t{c.spec.index}-{c.seq}-end", "seq": c.seq * 100 + 99,
                   "linear_mps": 0.0, "angular_radps": 0.0})
    c.seq += 1


async def _malformed(c: SoakClient) -> None:
    ws = c._ws
    if ws is None or ws.closed:
        raise ConnectionResetError("not connected")
    c._malformed_waiting += 1
    c.ledger.malformed_sent += 1
    await ws.send_str(["{not json", "[1, 2]", '{"op": 5}'][int(c.rng.integers(3))])


async def _invalid(c: SoakClient) -> None:
    body = dict(INVALID[int(c.rng.integers(len(INVALID)))])
    action = str(body.pop("action"))
    await c.command(action, expect="refusal", **body)


async def _viewer_command(c: SoakClient) -> None:
    action = ["go_home", "pause", "estop", "start_tour"][int(c.rng.integers(4))]
    await c.command(action, expect="refusal")


async def _kiosk_forbidden(c: SoakClient) -> None:
    await c.command(["go_home", "pause", "select_path"][int(c.rng.integers(3))],
                    expect="refusal", path_id=1)


async def _path_edit(c: SoakClient) -> None:
    """Add a waypoint to (or remove one from) the client's scratch path, over REST."""
    from curio.soak.clients import GOOD_POINTS

    edits = c.path
    http = c._http
    if edits is None or http is None:
        return
    base = c._url("/api/paths")
    if base is None:
        return
    headers = {**c._headers(), "Content-Type": "application/json"}
    timeout = aiohttp.ClientTimeout(total=5.0)
    if edits.path_id is None:
        async with http.post(base, data=json.dumps({"name": edits.name}), headers=headers,
                             timeout=timeout) as resp:
            if resp.status == 201:
                edits.path_id = int((await resp.json())["id"])
                edits.acked = []
            return
    wps = list(edits.acked)
    if wps and (len(wps) >= 8 or c.rng.uniform() < 0.3):
        index = int(c.rng.integers(len(wps)))
        target = wps[:index] + wps[index + 1:]
        request = http.delete(f"{base}/{edits.path_id}/waypoints/{index}", headers=headers,
                              timeout=timeout)
    else:
        x, y = GOOD_POINTS[int(c.rng.integers(len(GOOD_POINTS)))]
        point = (round(x + float(c.rng.uniform(-0.3, 0.3)), 3),
                 round(y + float(c.rng.uniform(-0.3, 0.3)), 3))
        target = [*wps, point]
        request = http.post(f"{base}/{edits.path_id}/waypoints",
                            data=json.dumps({"x_m": point[0], "y_m": point[1]}),
                            headers=headers, timeout=timeout)
    edits.in_flight = target
    async with request as resp:
        body: Any = await resp.json(content_type=None)
        if resp.status in (200, 201) and isinstance(body, dict):
            edits.acked = [(round(float(w["x_m"]), 3), round(float(w["y_m"]), 3))
                           for w in body.get("waypoints", [])]
            edits.edits += 1
        else:
            edits.failures += 1
            if resp.status == 404:  # the path is gone (a corrupt paths file was reset)
                edits.path_id = None
    edits.in_flight = None


async def perform(c: SoakClient, name: str) -> None:
    """Do action ``name`` (see the tables in :mod:`curio.soak.clients`)."""
    if name in ("go_home", "stop_tour", "cancel", "help_done", "start_tour"):
        await c.command(name)
    elif name == "select_path":
        await c.command("select_path", path_id=int(c.rng.choice([1, 2, 0])))
    elif name == "ping":
        await c._send({"op": "ping", "id": f"p{c.spec.index}-{c.seq}"})
    else:
        fn = {"pause_resume": _pause_resume, "estop_release": _estop_release, "goto": _goto,
              "teleop": _teleop, "malformed": _malformed, "invalid": _invalid,
              "viewer_command": _viewer_command, "kiosk_forbidden": _kiosk_forbidden,
              "path_edit": _path_edit}[name]
        await fn(c)
