"""The soak's dashboard clients: viewers, operators and a kiosk over real WebSockets.

Each :class:`SoakClient` connects to the rover's dashboard with its named token (none for a
viewer), lowers its stream rate (``{"op": "rate"}``), then, at random intervals, sends one of a
weighted set of messages: valid commands (pause and resume, go home, paths, tours, goals,
help done, the e-stop and its release, a short teleop burst), invalid ones (an unknown action,
a goal off the map, a path that does not exist, a viewer's command, malformed JSON), and path
edits over REST on a scratch path of its own. It drops its connection at random and reconnects,
and reconnects whenever the rover restarts.

Every command carries a ``request_id`` of its own and is entered in the
:class:`~curio.soak.ledger.Ledger`; answers are taken from the socket (live and in the history
a reconnecting page receives) and, after a reconnection, asked for over REST
(``GET /api/commands/{request_id}``) for the commands still without one.

Path edits are tracked too (:class:`PathEdits`): what the rover acknowledged must be in its
paths file after a ``kill -9``.

Timing is the orchestrator's wall clock (the clients are outside the rover, like people).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import aiohttp
import numpy as np

from curio.core.clock import RealClock, wall_perf_counter
from curio.soak.ledger import ANSWER_KINDS, Ledger

__all__ = ["ClientSpec", "PathEdits", "SoakClient", "answer_in_event", "answer_in_lookup",
           "client_specs"]

log = logging.getLogger("curio.soak.clients")

WALL = RealClock()  # the clients live on wall time, like the people they stand for

GOOD_POINTS = [(2.0, -2.5), (12.5, 1.5), (1.0, 11.8), (19.5, 12.0), (6.0, 0.0), (0.5, 0.5)]
STREAM_HZ = 0.5
MEAN_GAP_S = {"viewer": 40.0, "operator": 12.0, "kiosk": 30.0}
MEAN_CONNECTED_S = 90.0

# (weight, name) of what an operator does; see SoakClient._act_*.
OPERATOR_ACTIONS = [
    (12, "pause_resume"), (4, "estop_release"), (5, "go_home"), (5, "select_path"),
    (8, "start_tour"), (2, "stop_tour"), (2, "cancel"), (5, "goto"), (4, "help_done"),
    (4, "teleop"), (5, "path_edit"), (14, "invalid"), (2, "malformed"), (4, "ping"),
]
VIEWER_ACTIONS = [(4, "viewer_command"), (6, "ping"), (1, "malformed")]
KIOSK_ACTIONS = [(4, "start_tour"), (1, "stop_tour"), (3, "kiosk_forbidden"), (2, "ping")]


def answer_in_event(record: dict[str, Any]) -> tuple[str, str, str, float] | None:
    """``(request_id, kind, message, wall_s)`` of an answer in a dashboard event record (live
    or in a page's history), or None. Keyed by the answer's wall time, which a lookup gives
    too, so the same answer seen live and asked for after a reconnection is one answer."""
    if record.get("kind") not in ANSWER_KINDS:
        return None
    detail = record.get("detail") or {}
    rid = detail.get("request_id")
    if not isinstance(rid, str):
        return None
    return rid, str(record["kind"]), str(detail.get("message", "")), float(record.get("wall", 0))


def answer_in_lookup(rid: str, got: dict[str, Any]) -> tuple[str, str, str, float] | None:
    """The same from ``GET /api/commands/{rid}`` (its ``answer``), or None."""
    answer = got.get("answer")
    if not isinstance(answer, dict) or answer.get("kind") not in ANSWER_KINDS:
        return None
    return rid, str(answer["kind"]), str(answer.get("message", "")), float(
        answer.get("wall_s", 0.0))


@dataclass(frozen=True)
class ClientSpec:
    """One client: its number, role, token name and token (None for a viewer)."""

    index: int
    role: str
    name: str
    token: str | None

    @property
    def label(self) -> str:
        """``<role>:<name>#<index>``."""
        return f"{self.role}:{self.name}#{self.index}"


def client_specs(n: int, tokens: dict[str, str]) -> list[ClientSpec]:
    """``n`` clients: every third a viewer, one kiosk, the rest operators with their tokens
    (``tokens``: name → token, from the orchestrator's token store)."""
    out = []
    for i in range(n):
        if i % 3 == 0:
            out.append(ClientSpec(i, "viewer", f"viewer{i}", None))
        elif i == 2:
            out.append(ClientSpec(i, "kiosk", "kiosk", tokens["kiosk"]))
        else:
            name = f"op{i}"
            out.append(ClientSpec(i, "operator", name, tokens[name]))
    return out


@dataclass
class PathEdits:
    """A client's scratch path: the waypoints the rover acknowledged, and the edit in flight
    (which a ``kill -9`` may or may not have persisted)."""

    name: str
    path_id: int | None = None
    acked: list[tuple[float, float]] = field(default_factory=list)
    in_flight: list[tuple[float, float]] | None = None
    edits: int = 0
    failures: int = 0


class SoakClient:
    """One scripted dashboard client (see the module docstring).

    Args:
        spec: who it is.
        ledger: where commands and answers go.
        rng: its random source (from the soak's seed).
        address: returns the dashboard's ``(host, port)``, or None while the rover is down.
    """

    def __init__(self, spec: ClientSpec, ledger: Ledger, rng: np.random.Generator,
                 address: Callable[[], tuple[str, int] | None]) -> None:
        self.spec = spec
        self.ledger = ledger
        self.rng = rng
        self.address = address
        self.seq = 0
        self.connects = 0
        self.refused_connects = 0
        self.drops = 0
        self.messages_in = 0
        self.protocol_errors: list[str] = []
        self.path = PathEdits(f"soak {spec.name}") if spec.role == "operator" else None
        self._ws: aiohttp.ClientWebSocketResponse | None = None
        self._http: aiohttp.ClientSession | None = None
        self._malformed_waiting = 0
        self.stopping = False

    # --- plumbing -------------------------------------------------------------------------------

    def _headers(self) -> dict[str, str]:
        return {"X-Curio-Token": self.spec.token} if self.spec.token else {}

    def _url(self, path: str, ws: bool = False) -> str | None:
        addr = self.address()
        if addr is None:
            return None
        return f"{'ws' if ws else 'http'}://{addr[0]}:{addr[1]}{path}"

    def _rid(self) -> str:
        self.seq += 1
        return f"c{self.spec.index}-{self.seq}"

    async def _send(self, body: dict[str, Any]) -> None:
        ws = self._ws
        if ws is None or ws.closed:
            raise ConnectionResetError("not connected")
        await ws.send_str(json.dumps(body))

    async def command(self, action: str, expect: str = "answer", **fields: Any) -> str:
        """Send ``{"op": "command", "action", ...}`` with a new request id; return it."""
        rid = self._rid()
        self.ledger.sent(rid, self.spec.label, action, expect, wall_perf_counter())
        await self._send({"op": "command", "id": rid, "request_id": rid, "action": action,
                          **fields})
        return rid

    # --- the life of a client ---------------------------------------------------------------------

    async def run(self) -> None:
        """Connect, act, drop, reconnect ... until :attr:`stopping`."""
        async with aiohttp.ClientSession() as http:
            self._http = http
            while not self.stopping:
                url = self._url("/ws", ws=True)
                if url is None:
                    await WALL.sleep(0.2)
                    continue
                try:
                    ws = await http.ws_connect(url, headers=self._headers(),
                                               protocols=("curio.v1",), heartbeat=None,
                                               timeout=aiohttp.ClientWSTimeout(ws_close=1.0))
                except (TimeoutError, aiohttp.ClientError, OSError):
                    self.refused_connects += 1
                    await WALL.sleep(float(self.rng.uniform(0.2, 1.0)))
                    continue
                self.connects += 1
                await self._session(ws)
                if not self.stopping:
                    await WALL.sleep(float(self.rng.uniform(0.1, 2.0)))
        self._http = None

    async def _session(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self._ws = ws
        reader = asyncio.ensure_future(self._read(ws))
        actor = asyncio.ensure_future(self._act())
        try:
            with contextlib.suppress(ConnectionResetError, aiohttp.ClientError):
                await self._send({"op": "rate", "hz": STREAM_HZ})
            await self._reconcile()
            _done, _ = await asyncio.wait({reader, actor}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            actor.cancel()
            with contextlib.suppress(BaseException):
                await actor
            if not ws.closed:
                with contextlib.suppress(Exception):
                    await ws.close()
            reader.cancel()
            with contextlib.suppress(BaseException):
                await reader
            self._ws = None
            for rec in self.ledger.pending(self.spec.label):
                rec.disconnected = True

    async def _read(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        async for msg in ws:
            if msg.type == aiohttp.WSMsgType.TEXT:
                self.messages_in += 1
                try:
                    self._on_message(json.loads(msg.data))
                except (ValueError, KeyError, TypeError) as exc:
                    self.protocol_errors.append(f"{type(exc).__name__}: {exc}")
            elif msg.type == aiohttp.WSMsgType.BINARY:
                self.messages_in += 1
            elif msg.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                break

    def _on_message(self, msg: dict[str, Any]) -> None:
        t = msg.get("t")
        if t == "ack":
            rid = msg.get("request_id") or msg.get("id")
            if isinstance(rid, str):
                self.ledger.acked(rid, bool(msg.get("duplicate")))
        elif t == "error":
            rid = msg.get("id")
            if isinstance(rid, str) and rid in self.ledger.commands:
                self.ledger.answer(rid, "refused", str(msg.get("message", "")), 0.0, "refusal")
            elif rid is None and self._malformed_waiting and msg.get("code") != "rate_limited":
                self._malformed_waiting -= 1
                self.ledger.malformed_refused += 1
        elif t == "event":
            self._on_event(msg["event"], "ws")
        elif t == "state":
            for record in msg.get("events", []):
                self._on_event(record, "history")

    def _on_event(self, record: dict[str, Any], via: str) -> None:
        answer = answer_in_event(record)
        if answer is not None and answer[0].startswith(f"c{self.spec.index}-"):
            self.ledger.answer(*answer, via)

    async def _reconcile(self) -> None:
        """Ask the rover about every command of this client still without an answer."""
        for rec in self.ledger.pending(self.spec.label):
            if not rec.disconnected:
                continue
            got = await self.lookup(rec.rid)
            if got is None:
                continue
            state = str(got.get("state", ""))
            rec.lookups.append(state)
            answer = answer_in_lookup(rec.rid, got)
            if answer is not None:
                self.ledger.answer(*answer, "lookup")

    async def lookup(self, rid: str) -> dict[str, Any] | None:
        """``GET /api/commands/{rid}`` (None when the rover cannot be asked). Works after the
        client stopped too (the soak's last questions): then with a session of its own."""
        url = self._url(f"/api/commands/{rid}")
        if url is None:
            return None
        if self._http is not None and not self._http.closed:
            return await self._get_json(self._http, url)
        async with aiohttp.ClientSession() as http:
            return await self._get_json(http, url)

    async def _get_json(self, http: aiohttp.ClientSession, url: str) -> dict[str, Any] | None:
        try:
            async with http.get(url, headers=self._headers(),
                                timeout=aiohttp.ClientTimeout(total=5.0)) as resp:
                if resp.status != 200:
                    return {"state": f"http {resp.status}"}
                data = await resp.json()
                return data if isinstance(data, dict) else None
        except (TimeoutError, aiohttp.ClientError, OSError, ValueError):
            return None

    # --- acting -----------------------------------------------------------------------------------

    def _choose(self) -> str:
        table = {"viewer": VIEWER_ACTIONS, "kiosk": KIOSK_ACTIONS}.get(self.spec.role,
                                                                         OPERATOR_ACTIONS)
        weights = np.array([w for w, _ in table], dtype=float)
        return table[int(self.rng.choice(len(table), p=weights / weights.sum()))][1]

    async def _act(self) -> None:
        mean = MEAN_GAP_S.get(self.spec.role, 20.0)
        leave_at = wall_perf_counter() + float(self.rng.exponential(MEAN_CONNECTED_S))
        while not self.stopping:
            await WALL.sleep(float(self.rng.exponential(mean)))
            if wall_perf_counter() >= leave_at:
                self.drops += 1
                return
            try:
                await perform(self, self._choose())
            except (ConnectionResetError, aiohttp.ClientError, OSError):
                return


# --- what a client does, one function per action (perform picks by name) -----------------
# Valid commands expect the rover's answer (bt.command_accepted / rejected); invalid ones
# expect the dashboard to refuse them with a reason. Path edits go over REST on the client's
# scratch path and are tracked in its PathEdits.

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
    await c.command("pause")
    await WALL.sleep(float(c.rng.uniform(0.5, 4.0)))
    await c.command("resume")


async def _estop_release(c: SoakClient) -> None:
    await c.command("estop")
    await WALL.sleep(float(c.rng.uniform(0.5, 5.0)))
    await c.command("release_estop")


async def _goto(c: SoakClient) -> None:
    x, y = GOOD_POINTS[int(c.rng.integers(len(GOOD_POINTS)))]
    await c.command("goto", goal={"x_m": x, "y_m": y})


async def _teleop(c: SoakClient) -> None:
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
    """Do action ``name`` (see the tables above)."""
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
