"""Fixtures for the dashboard tests: a fake path manager and a dashboard on a fake app."""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import aiohttp
import numpy as np
import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage
from curio.core.parts import Parts
from curio.core.topics import MAP
from curio.estimation.maps import OccupancyGrid
from curio.eventlog.store import EventLog
from curio.record.codec import Codec
from curio.record.mcap_sink import McapSink
from curio.robot import RobotModel
from curio.tours.wiring import Tours, build_tours
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

    def ids(self) -> list[int]:
        return sorted(self.paths)

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


# --- a dashboard on the real tours subsystem, event log and recordings ---------------------------

LONDON = ZoneInfo("Europe/London")
# Monday 2 June 2025, 09:00 in London: the clock's wall time at now() == 0.
MONDAY_9 = dt.datetime(2025, 6, 2, 9, 0, tzinfo=LONDON).timestamp()


async def ok(resp: Any, status: int = 200) -> Any:
    """The JSON of a response that must have ``status``."""
    data = await resp.json()
    assert resp.status == status, data
    return data


async def refused(resp: Any, status: int, *words: str) -> str:
    """The error sentence of a response that must be refused with ``status`` and ``words``."""
    data = await resp.json()
    assert resp.status == status, data
    for word in words:
        assert word in data["error"], data["error"]
    return str(data["error"])


def building() -> OccupancyGrid:
    """30 m x 20 m from (-5, -5) at 0.1 m: walls all round and a wall block at x 8–9, y 0–5."""
    data = np.zeros((200, 300), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[50:100, 130:140] = 100
    return OccupancyGrid(data, 0.1, Pose2D(-5.0, -5.0, 0.0), name="building")


@dataclass
class TourDash:
    """A dashboard on the real tours subsystem and event log."""

    client: TestClient
    bus: Bus
    clock: SimClock
    tours: Tours
    log: EventLog
    cfg: Config
    recordings: Path


MakeTourDash = Callable[..., Awaitable[TourDash]]


@pytest.fixture
async def make_tour_dash(aiohttp_client: Any, cfg: Config, bus: Bus, tmp_path: Path
                         ) -> AsyncIterator[MakeTourDash]:
    """Build a dashboard with real tours (tree = tour, Europe/London, Monday 09:00), an event
    log and a recordings directory in ``tmp_path``."""
    logs: list[EventLog] = []

    async def make(replay: Any = None) -> TourDash:
        cfg.bt.tree = "tour"
        cfg.tours.timezone = "Europe/London"
        clock = SimClock(epoch_wall_s=MONDAY_9)
        grid = building()
        bus.publish(MAP, GridMessage(0.0, grid.data, grid.resolution_m, grid.origin))
        robot = RobotModel.from_config(cfg.robot)
        tours = build_tours(cfg, bus, clock, Parts(), robot, lambda: grid, FakePaths())
        log = EventLog(tmp_path / "events.sqlite3")
        logs.append(log)
        recordings = tmp_path / "recordings"
        recordings.mkdir(exist_ok=True)
        app = create_app(WebServices(
            cfg=cfg, clock=clock, bus=bus, tokens=make_tokens(tmp_path / "tokens.json"),
            robot=robot, paths=FakePaths(), tours=tours, eventlog=log,
            recordings_dir=recordings, replay=replay))
        return TourDash(await aiohttp_client(app), bus, clock, tours, log, cfg, recordings)

    yield make
    for log in logs:
        log.close()


# --- data for the log, report and recordings pages ---------------------------------------------


def at(hhmm: str, day: int = 2) -> float:
    """UNIX seconds of June ``day`` 2025, ``hhmm`` in London."""
    h, m = (int(v) for v in hhmm.split(":"))
    return dt.datetime(2025, 6, day, h, m, tzinfo=LONDON).timestamp()


def fill_log(log: EventLog) -> None:
    """Two days of a museum's records (1 and 2 June 2025)."""
    for day in (1, 2):
        log.append("tour.started", {"tour": "Highlights", "source": "kiosk:lobby", "stops": 2},
                   wall_s=at("10:00", day), source="kiosk:lobby")
        log.append("tour.stop", {"name": "Lobby"}, wall_s=at("10:02", day))
        log.append("tour.finished", {"stops_reached": 2, "stops": 2, "duration_s": 600},
                   wall_s=at("10:10", day))
    log.append("help.requested", {"message": "the door is shut"}, wall_s=at("11:00"))
    log.append("help.resolved", {"waited_s": 42.0}, wall_s=at("11:00") + 42)
    log.append("tour.skipped", {"tour": "North wing", "reason": "the battery is low",
                                "due": "2025-06-02T13:00"}, wall_s=at("13:00"))
    log.append("operator.go_home", {"request_id": "r1"}, wall_s=at("12:00"), source="web:alice")
    assert log.flush()


def write_recording(directory: Path, start: float, events: list[str]) -> str:
    """A small complete recording starting at UNIX ``start`` with these /events kinds."""
    codec = Codec(start)
    sink = McapSink(directory=directory, file=None, started_wall_s=start,
                    metadata={"format": "curio-recording"}, max_file_bytes=10**9,
                    max_file_s=1e9, max_total_bytes=10**10)
    spec = codec.spec("/events")
    for i, kind in enumerate(events):
        ns = int((start + 60.0 * i) * 1e9)
        sink.write(spec, ns, ns, i, json.dumps({"stamp": i, "kind": kind,
                                                "detail": {}}).encode())
    sink.close()
    return sink.files[0].name
