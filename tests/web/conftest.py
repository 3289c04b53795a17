"""Fixtures for the dashboard tests: a fake path manager and a dashboard on a fake app."""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.robot import RobotModel
from curio.web.hub import Hub
from curio.web.server import create_app
from curio.web.services import HUB, WebServices
from curio.web.tokens import TokenEntry, TokenStore

TOKEN = "test-token-0123456789abcdef"  # the admin token "admin"
ALICE = "alice-token-0123456789abcdef"  # operator "alice"
BOB = "bob-token-0123456789abcdef00"  # operator "bob"
KIOSK = "kiosk-token-0123456789abcdef"  # kiosk "lobby"


def make_tokens(path: Path) -> TokenStore:
    """A token store with an admin, two operators and a kiosk."""
    store = TokenStore(path)
    store._set([TokenEntry("admin", "admin", TOKEN, "test"),
                TokenEntry("alice", "operator", ALICE, "test"),
                TokenEntry("bob", "operator", BOB, "test"),
                TokenEntry("lobby", "kiosk", KIOSK, "test")])
    store._save()
    return store


def bearer(token: str) -> dict[str, str]:
    """The Authorization header for ``token``."""
    return {"Authorization": f"Bearer {token}"}


class FakePathError(ValueError):
    """Same contract as the path manager's PathError: an operator-facing message."""


@dataclass
class FakeWaypoint:
    x_m: float
    y_m: float
    yaw_rad: float | None = None


@dataclass
class FakePath:
    id: int
    name: str
    waypoints: list[FakeWaypoint] = field(default_factory=list)


class FakePaths:
    """In-memory path manager with the interface of ``app.paths``."""

    def __init__(self, n: int = 5) -> None:
        self.paths = {i: FakePath(i, "Home" if i == 0 else f"Path {i}",
                                  [FakeWaypoint(float(i), 0.0)]) for i in range(n)}
        self.next_id = n

    def list_paths(self) -> list[FakePath]:
        return [self.paths[i] for i in sorted(self.paths)]

    def get(self, path_id: int) -> FakePath:
        if path_id not in self.paths:
            raise FakePathError(f"There is no path {path_id}.")
        return self.paths[path_id]

    def create(self, name: str, waypoints: Any = ()) -> FakePath:
        if not name.strip():
            raise FakePathError("A path needs a name.")
        p = FakePath(self.next_id, name)
        self.paths[p.id] = p
        self.next_id += 1
        return p

    def add_waypoint(self, path_id: int, x_m: float, y_m: float,
                     yaw_rad: float | None = None) -> FakePath:
        p = self.get(path_id)
        p.waypoints.append(FakeWaypoint(x_m, y_m, yaw_rad))
        return p

    def replace_waypoints(self, path_id: int, waypoints: Any) -> FakePath:
        p = self.get(path_id)
        if path_id == 0 and not waypoints:
            raise FakePathError("Home must keep at least one waypoint.")
        p.waypoints = [FakeWaypoint(w.x_m, w.y_m, w.yaw_rad) for w in waypoints]
        return p

    def remove_waypoint(self, path_id: int, index: int) -> FakePath:
        p = self.get(path_id)
        if not 0 <= index < len(p.waypoints):
            raise FakePathError(f"Path {path_id} has no waypoint {index}.")
        del p.waypoints[index]
        return p

    def rename(self, path_id: int, name: str) -> FakePath:
        p = self.get(path_id)
        if not name.strip():
            raise FakePathError("A path needs a name.")
        p.name = name
        return p

    def delete(self, path_id: int) -> None:
        if path_id == 0:
            raise FakePathError("Home (path 0) cannot be deleted.")
        self.get(path_id)
        del self.paths[path_id]


@dataclass
class Dash:
    """A dashboard under test."""

    client: TestClient
    hub: Hub
    bus: Bus
    clock: SimClock
    paths: FakePaths
    cfg: Config
    tokens: TokenStore

    @property
    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {TOKEN}"}


MakeDash = Callable[..., Awaitable[Dash]]


@pytest.fixture(params=["desktop", "phone"])
def viewport(request: pytest.FixtureRequest) -> str:
    """The browser tests' viewports: desktop 1280×800 and phone 390×844."""
    return str(request.param)


async def recv_json_until(
    ws: aiohttp.ClientWebSocketResponse, pred: Callable[[dict[str, Any]], bool],
    limit: int = 500,
) -> dict[str, Any]:
    """Read messages until a JSON one satisfies ``pred`` (binary frames are skipped)."""
    for _ in range(limit):
        msg = await ws.receive(timeout=5.0)
        if msg.type == WSMsgType.TEXT:
            data = json.loads(msg.data)
            if pred(data):
                return data
        elif msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSED, WSMsgType.ERROR):
            raise AssertionError(f"socket closed: {msg}")
    raise AssertionError("message not received")


@pytest.fixture
def make_dash(aiohttp_client: Any, cfg: Config, bus: Bus, tmp_path: Path) -> MakeDash:
    """Build the dashboard with fakes; keyword arguments override ``cfg.web`` fields."""

    async def make(**web_overrides: Any) -> Dash:
        for key, value in web_overrides.items():
            setattr(cfg.web, key, value)
        clock = SimClock()
        paths = FakePaths()
        tokens = make_tokens(tmp_path / "tokens.json")
        app = create_app(WebServices(cfg=cfg, clock=clock, bus=bus, tokens=tokens,
                                     robot=RobotModel.from_config(cfg.robot), paths=paths))
        client = await aiohttp_client(app)
        return Dash(client, app[HUB], bus, clock, paths, cfg, tokens)

    return make
