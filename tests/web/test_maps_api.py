"""The map library over REST, on the real App rebuilt by ``curio run``'s host (MapHost) on a
real-time SimClock: listing, upload (and its refusals), rename, floors, delete; switching the
active map (paths, tours and zones stay with their map; refused during a tour; the choice
survives a restart; the pose is asked for); cell edits saved as revisions and used by the
costmap and the localiser; restoring a revision; a mapping run saved as a new map.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np

from curio.commands.host import MapHost
from curio.core.clock import Clock
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, CMD_VEL_TELEOP, TOUR
from curio.estimation.localization import LocalizerNode
from curio.nav.costs import LETHAL
from curio.web.tokens import TokenStore
from tests.web.maps_kit import hosted

SHIPPED = REPO_ROOT / "maps" / "curio_building"


def _cfg(tmp_path: Path, *extra: str) -> Config:
    return load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path / "data"}"', "web.enabled=true", "web.port=0", "bt.speak=false",
        "record.enabled=false", *extra])


def _token(cfg: Config) -> str:
    """A new operator token (a new name each time: a restarted host reuses the data dir)."""
    store = TokenStore(cfg.data_path(cfg.web.tokens_file), cfg.data_path(cfg.web.token_file))
    store.ensure_admin()
    return store.create(f"alice{len(store.entries())}", "operator").token


class Rest:
    """A client with the operator's token that waits for the rover across rebuilds."""

    def __init__(self, session: aiohttp.ClientSession, base: str, token: str,
                 clock: Clock) -> None:
        self.s, self.base, self.auth = session, base, {"Authorization": f"Bearer {token}"}
        self.clock = clock  # waits in simulated time (3× the wall clock)

    async def call(self, method: str, path: str, body: Any = None, *, auth: bool = True,
                   data: Any = None) -> tuple[int, Any]:
        for _ in range(200):  # the server is down for a moment while the App is rebuilt
            try:
                async with self.s.request(method, self.base + path, json=body, data=data,
                                          headers=self.auth if auth else {}) as r:
                    return r.status, await r.json()
            except aiohttp.ClientConnectionError:
                await self.clock.sleep(0.3)
        raise AssertionError(f"{method} {path}: the rover never answered")

    async def settled(self, host: MapHost, generation: int) -> None:
        """Wait until the host has built App number ``generation`` and it answers."""
        for _ in range(300):
            if host.generation >= generation and not host.state()["switching"]:
                status, _ = await self.call("GET", "/api/maps")
                if status == 200:
                    return
            await self.clock.sleep(0.3)
        raise AssertionError(f"the host never built App {generation}: {host.state()}")


@contextlib.asynccontextmanager
async def _rover(tmp_path: Path, *extra: str, speed: float = 3.0
                 ) -> AsyncIterator[tuple[MapHost, Rest]]:
    """The host on a fresh data dir (or the same one again) and an operator's client."""
    cfg = _cfg(tmp_path, *extra)
    token = _token(cfg)
    async with hosted(cfg, speed) as (host, base), aiohttp.ClientSession() as s:
        yield host, Rest(s, base, token, host.clock)


def _upload(name: str, floor: str, yaml_text: str | None = None,
            image: bytes | None = None) -> aiohttp.FormData:
    form = aiohttp.FormData()
    form.add_field("name", name)
    form.add_field("floor", floor)
    form.add_field("yaml", yaml_text if yaml_text is not None else
                   SHIPPED.with_suffix(".yaml").read_text(), filename="annex.yaml")
    form.add_field("image", image if image is not None else
                   SHIPPED.with_suffix(".pgm").read_bytes(), filename="annex.pgm")
    return form


async def test_library_list_upload_rename_floor_delete(tmp_path: Path) -> None:
    async with _rover(tmp_path) as (_host, rest):
        status, body = await rest.call("GET", "/api/maps", auth=False)
        assert status == 200 and body["active"] == "curio_building"
        [seed] = body["maps"]
        assert (seed["floor"], seed["width_cells"], seed["height_cells"], seed["resolution_m"],
                seed["active"], seed["has_world"]) == ("Ground floor", 600, 400, 0.05, True, True)
        # A viewer may look but not change.
        status, body = await rest.call("POST", "/api/maps/import", data=_upload("x", ""),
                                       auth=False)
        assert status == 401 and "token" in body["error"]
        # An upload larger than web.max_message_bytes (the PGM is 240 kB) is accepted.
        status, body = await rest.call("POST", "/api/maps/import",
                                       data=_upload("annex", "First floor"))
        assert status == 201, body
        assert body["map"]["floor"] == "First floor" and body["map"]["source"] == "upload"
        # Wrong uploads: one sentence each.
        for form, words in [
            (_upload("bad", "", yaml_text="image: a.pgm\nresolution: -1\norigin: [0, 0, 0]\n"),
             "resolution' must be > 0"),
            (_upload("bad", "", yaml_text="[unclosed"), "not valid YAML"),
            (_upload("bad", "", image=b"not an image"), "cannot read"),
            (_upload("annex", ""), "is taken"),
            (_upload("../etc", ""), "is not allowed"),
        ]:
            status, body = await rest.call("POST", "/api/maps/import", data=form)
            assert status == 400 and words in body["error"], body
            assert "\n" not in body["error"]
        # Rename and relabel; the active map can be neither renamed nor deleted.
        status, body = await rest.call("PATCH", "/api/maps/annex",
                                       {"name": "annex2", "floor": "Level 1"})
        assert status == 200 and body["map"]["name"] == "annex2", body
        status, body = await rest.call("PATCH", "/api/maps/curio_building", {"name": "x"})
        assert status == 400 and "active map" in body["error"]
        status, body = await rest.call("DELETE", "/api/maps/curio_building")
        assert status == 400 and "active map" in body["error"]
        _, body = await rest.call("GET", "/api/maps")
        assert {m["name"]: m["floor"] for m in body["maps"]} == {
            "annex2": "Level 1", "curio_building": "Ground floor"}
        status, _ = await rest.call("DELETE", "/api/maps/annex2")
        assert status == 200
        _, body = await rest.call("GET", "/api/maps")
        assert [m["name"] for m in body["maps"]] == ["curio_building"]


async def _make_things(rest: Rest, label: str) -> None:
    """A path, a tour and a keep-out zone on the active map, named after ``label``."""
    status, body = await rest.call("POST", "/api/paths", {"name": f"path {label}"})
    assert status in (200, 201), body
    status, body = await rest.call("POST", "/api/tours", {"name": f"tour {label}", "stops": [
        {"name": "Lobby", "x_m": 2.0, "y_m": -2.5}]})
    assert status == 201, body
    status, body = await rest.call("POST", "/api/zones", {
        "name": f"zone {label}", "kind": "keepout",
        "polygon": [[10.5, 1.5], [11.5, 1.5], [11.5, 2.5], [10.5, 2.5]]})
    assert status == 201, body


async def _things(rest: Rest) -> tuple[set[str], set[str], set[str]]:
    _, paths = await rest.call("GET", "/api/paths")
    _, tours = await rest.call("GET", "/api/tours")
    _, zones = await rest.call("GET", "/api/zones")
    path_list = paths["paths"] if isinstance(paths, dict) else paths
    return ({p["name"] for p in path_list}, {t["name"] for t in tours["tours"]},
            {z["name"] for z in zones["zones"]})


async def test_switching_keeps_paths_tours_and_zones_with_their_map(tmp_path: Path) -> None:
    async with _rover(tmp_path) as (host, rest):
        status, _ = await rest.call("POST", "/api/maps/import", data=_upload("annex", "1"))
        assert status == 201
        await _make_things(rest, "A")
        paths_a, tours_a, zones_a = await _things(rest)
        assert "path A" in paths_a and "tour A" in tours_a and zones_a == {"zone A"}

        status, body = await rest.call("POST", "/api/maps/active", {"name": "annex"})
        assert status == 202 and "set its pose" in body["message"], body
        await rest.settled(host, 2)
        _, body = await rest.call("GET", "/api/maps")
        assert body["active"] == "annex" and body["state"]["pose_needed"] is True
        paths_b, tours_b, zones_b = await _things(rest)
        assert "path A" not in paths_b and "tour A" not in tours_b and zones_b == set()
        await _make_things(rest, "B")
        # The pose is asked for until somebody relocalises or sets it.
        status, _ = await rest.call("POST", "/api/relocalise")
        assert status == 202
        for _ in range(50):
            _, body = await rest.call("GET", "/api/maps")
            if not body["state"]["pose_needed"]:
                break
            await host.clock.sleep(0.15)
        assert body["state"]["pose_needed"] is False

        status, body = await rest.call("POST", "/api/maps/active", {"name": "annex"})
        assert status == 400 and "already the active map" in body["error"]
        status, body = await rest.call("POST", "/api/maps/active", {"name": "nowhere"})
        assert status == 400 and "there is no map 'nowhere'" in body["error"]
        status, _ = await rest.call("POST", "/api/maps/active", {"name": "curio_building"})
        assert status == 202
        await rest.settled(host, 3)
        paths, tours, zones = await _things(rest)
        assert "path A" in paths and "path B" not in paths
        assert "tour A" in tours and "tour B" not in tours and zones == {"zone A"}

    # The choice survives a restart (a new host on the same data directory).
    async with _rover(tmp_path) as (host, rest):
        _, body = await rest.call("GET", "/api/maps")
        assert body["active"] == "curio_building" and host.generation == 1


async def test_switching_stops_the_rover_first(tmp_path: Path) -> None:
    """Driven by teleop until the switch: the safety stage ramps the rover to a standstill
    (zero on /cmd_vel) before the old App stops."""
    async with _rover(tmp_path) as (host, rest):
        await rest.call("POST", "/api/maps/import", data=_upload("annex", "1"))
        old = host.app
        assert old is not None
        seen: list[Twist] = []
        sub = old.bus.subscribe(CMD_VEL, maxsize=1000)

        async def record() -> None:
            async for msg in sub:
                seen.append(msg)

        recorder = asyncio.create_task(record())
        for _ in range(20):  # the joystick held forward for a while
            old.bus.publish(CMD_VEL_TELEOP, Twist(old.clock.now(), 0.25, 0.0, source="web"))
            await host.clock.sleep(0.15)
        assert max(m.linear_mps for m in seen) > 0.1, "the rover never drove"
        status, _ = await rest.call("POST", "/api/maps/active", {"name": "annex"})
        assert status == 202
        await rest.settled(host, 2)
        recorder.cancel()
        assert host.stand_still_s is not None and host.stand_still_s < 3.0
        # The safety stage itself brought it to zero, before the App's halt (source "halt").
        before_halt = seen[:next(i for i, m in enumerate(seen) if m.source == "halt")]
        assert before_halt[-1].linear_mps == 0.0 and before_halt[-1].angular_radps == 0.0
        assert before_halt[-1].source != "halt"


async def test_a_map_the_rover_cannot_run_on_leaves_it_on_its_map(tmp_path: Path) -> None:
    """A switch to a map whose tours file is damaged: the new App cannot be built, so the
    host starts the old map again and says why."""
    async with _rover(tmp_path) as (host, rest):
        await rest.call("POST", "/api/maps/import", data=_upload("annex", "1"))
        (host.library.root / "annex" / "tours.json").write_text('{"version": 2, "tours": [')
        status, _ = await rest.call("POST", "/api/maps/active", {"name": "annex"})
        assert status == 202
        await rest.settled(host, 2)
        _, body = await rest.call("GET", "/api/maps")
        assert body["active"] == "curio_building" and host.library.active == "curio_building"
        assert "NOT made" in body["state"]["message"] and "tours" in body["state"]["message"]
        assert body["state"]["pose_needed"] is False


async def test_switching_is_refused_while_a_tour_runs(tmp_path: Path) -> None:
    async with _rover(tmp_path, 'bt.tree="tour"') as (host, rest):
        await rest.call("POST", "/api/maps/import", data=_upload("annex", "1"))
        _, tours = await rest.call("GET", "/api/tours")
        tour_id = tours["tours"][0]["id"]
        status, body = await rest.call("POST", f"/api/tours/{tour_id}/start", {})
        assert status == 202, body
        assert host.app is not None
        for _ in range(100):
            state = host.app.bus.latest(TOUR)
            if state is not None and state.tour_id is not None:
                break
            await host.clock.sleep(0.15)
        status, body = await rest.call("POST", "/api/maps/active", {"name": "annex"})
        assert status == 409 and "is running: stop the tour first" in body["error"], body
        status, _ = await rest.call("POST", "/api/maps/mapping", {"action": "start"})
        assert status == 409
        assert host.generation == 1 and host.library.active == "curio_building"


async def test_cell_edits_are_revisions_used_by_costmap_and_localiser(tmp_path: Path) -> None:
    async with _rover(tmp_path) as (host, rest):
        status, grid = await rest.call("GET", "/api/maps/curio_building/cells", auth=False)
        assert status == 200 and grid["revision"] == 1
        assert (grid["width"], grid["height"]) == (600, 400)
        # A wall across free floor: row 150 (y = 1.525 m), columns 300..319 (x 9.0..10.0 m).
        assert host.app is not None
        before = host.app.map_server.grid.data[150, 300:320].copy()
        assert (before == 0).all(), "the test wall must go on free floor"
        status, body = await rest.call("POST", "/api/maps/curio_building/cells", {
            "revision": 1, "changes": [[150, 300, 20, 100]]}, auth=False)
        assert status == 401
        for changes, words in [([[150, 590, 20, 100]], "leave the map"),
                               ([[150, 300, 20, 50]], "value 50 is not allowed"),
                               ([], "non-empty list")]:
            status, body = await rest.call("POST", "/api/maps/curio_building/cells",
                                           {"revision": 1, "changes": changes})
            assert status == 400 and words in body["error"], body
        status, body = await rest.call("POST", "/api/maps/curio_building/cells", {
            "revision": 1, "changes": [[150, 300, 20, 100]]})
        assert status == 202 and body["revision"] == 2 and body["changed_cells"] == 20, body
        await rest.settled(host, 2)
        app = host.app
        assert app is not None
        assert (app.map_server.grid.data[150, 300:320] == 100).all()
        x, y = app.map_server.grid.cell_to_world(150, 310)
        assert app.costmap.cost_at(x, y) >= LETHAL  # the planner's and controller's costmap
        assert isinstance(app.localizer, LocalizerNode)
        loc = app.localizer.localizer
        assert (loc.grid.data[150, 300:320] == 100).all()
        assert loc.field.lookup(np.array([x]), np.array([y]))[0] < 0.05  # the likelihood field
        # A stale revision is refused (someone else saved meanwhile).
        status, body = await rest.call("POST", "/api/maps/curio_building/cells", {
            "revision": 1, "changes": [[150, 300, 20, 0]]})
        assert status == 400 and "reload it" in body["error"]
        _, listing = await rest.call("GET", "/api/maps")
        assert listing["maps"][0]["revisions"] == [1]
        # Undo the saved edit: revision 1 becomes current again (as revision 3).
        status, body = await rest.call("POST", "/api/maps/curio_building/restore",
                                       {"revision": 1})
        assert status == 202 and body["revision"] == 3, body
        await rest.settled(host, 3)
        assert host.app is not None
        np.testing.assert_array_equal(host.app.map_server.grid.data[150, 300:320], before)


async def test_mapping_run_saved_as_a_new_map(tmp_path: Path) -> None:
    async with _rover(tmp_path, speed=2.0) as (host, rest):
        status, body = await rest.call("POST", "/api/maps/mapping",
                                       {"action": "save", "name": "new"})
        assert status == 409 and "no mapping run" in body["error"]
        await rest.call("POST", "/api/maps/import", data=_upload("annex", "1"))
        status, body = await rest.call("POST", "/api/maps/mapping", {"action": "start"})
        assert status == 202, body
        await rest.settled(host, 2)
        assert host.mapping and host.app is not None
        # Nothing else changes maps during a run (it would be lost).
        status, body = await rest.call("POST", "/api/maps/active", {"name": "annex"})
        assert status == 409 and "mapping run is under way" in body["error"], body
        status, body = await rest.call("POST", "/api/maps/curio_building/cells", {
            "revision": 1, "changes": [[150, 300, 20, 100]]})
        assert status == 400 and "mapping run is under way" in body["error"], body
        _, live0 = await rest.call("GET", "/api/maps/live")
        # Drive by teleop (as the dashboard's joystick does) for a few simulated seconds.
        app = host.app
        for _ in range(40):
            app.bus.publish(CMD_VEL_TELEOP, Twist(app.clock.now(), 0.0, 0.6, source="web"))
            await host.clock.sleep(0.15)
        _, live = await rest.call("GET", "/api/maps/live")
        assert live["version"] > live0["version"], "the map did not grow"
        status, body = await rest.call("POST", "/api/maps/mapping",
                                       {"action": "save", "name": "curio_building"})
        assert status == 400 and "is taken" in body["error"]
        status, body = await rest.call("POST", "/api/maps/mapping",
                                       {"action": "save", "name": "scanned", "floor": "2"})
        assert status == 202, body
        await rest.settled(host, 3)
        _, listing = await rest.call("GET", "/api/maps")
        made = {m["name"]: m for m in listing["maps"]}["scanned"]
        assert made["source"] == "mapping" and made["floor"] == "2"
        assert listing["active"] == "curio_building" and not listing["state"]["mapping"]
        grid = host.library.grid("scanned")
        assert (grid.data == 100).sum() > 50 and (grid.data == 0).sum() > 500
