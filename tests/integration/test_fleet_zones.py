"""Zones distribution: the fleet manager's zones of the shared map reach a rover as a signed
``set_zones`` and its zone service applies them (keep-out lethal in the costmap); a kiosk key,
a keep-out over the rover and another map are refused; the manager pushes only to rovers whose
zones differ, and nothing while it has no zone file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from curio.core.config import REPO_ROOT, load_config
from curio.core.topics import POSE
from curio.fleet.auth import CommandSigner, KeyEntry
from curio.fleet.manager.roster import Roster
from curio.fleet.zones_sync import ZoneDistributor, zones_digest
from curio.zones.store import ZoneStore
from tests.integration.test_fleet_dock import FLEET, started_rover

LOBBY = KeyEntry("lobby", "kiosk", "l" * 32)
KEEPOUT = {"id": 4, "name": "Stairs", "kind": "keepout",
           "polygon": [[10.0, 8.0], [11.0, 8.0], [11.0, 9.0], [10.0, 9.0]],
           "speed_limit_mps": None}
SLOW = {"id": 7, "name": "Gallery", "kind": "speed",
        "polygon": [[12.0, 0.5], [14.0, 0.5], [14.0, 2.5], [12.0, 2.5]],
        "speed_limit_mps": 0.15}


async def test_a_rover_takes_the_managers_zones_and_refuses_bad_ones(tmp_path: Path) -> None:
    cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{tmp_path}"', "web.enabled=false", "bt.speak=false",
        "fleet.enabled=true", 'fleet.rover="r1"'])
    app, clock, them, statuses, replies = await started_rover(cfg, (FLEET, LOBBY))
    assert app.zones is not None
    map_name = app.zones.store.map_name

    def send(key: KeyEntry, rid: str, zones: list[dict[str, Any]], name: str = map_name
             ) -> None:
        them.put("curio/r1/cmd", CommandSigner(key, clock.wall_time).sign(
            "r1", {"action": "set_zones", "map": name, "zones": zones, "request_id": rid}))

    pose = app.bus.latest(POSE)
    assert pose is not None
    x, y = pose.pose.x, pose.pose.y
    over_me = {**KEEPOUT, "id": 9, "polygon": [[x - 1, y - 1], [x + 1, y - 1], [x + 1, y + 1],
                                               [x - 1, y + 1]]}
    send(LOBBY, "k", [KEEPOUT])                       # a kiosk key may not
    send(FLEET, "other", [KEEPOUT], "another_map")    # not this rover's map
    send(FLEET, "over", [KEEPOUT, over_me])           # a keep-out where the rover stands
    send(FLEET, "ok", [KEEPOUT, SLOW])
    await clock.run(until_s=4.0)
    them.pump()
    by_id = {r["request_id"]: r for r in replies}
    (kiosk,) = [r for r in replies if not r["request_id"]]  # refused before it was read
    assert not kiosk["ok"] and "may not set_zones" in kiosk["reason"], kiosk
    assert not by_id["other"]["ok"] and "another_map" in by_id["other"]["reason"]
    assert not by_id["over"]["ok"] and "covers the rover" in by_id["over"]["reason"]
    assert by_id["ok"]["ok"]
    assert [z.to_json() for z in app.zones.store.list_zones()] == [KEEPOUT, SLOW]
    assert app.costmap.cost_at(10.5, 8.5) >= 254  # the keep-out is lethal now
    assert statuses[-1]["zones"]["digest"] == zones_digest([KEEPOUT, SLOW])
    kept = ZoneStore(app.zones.store.path, map_name, 1.0)  # persisted
    assert [z.id for z in kept.list_zones()] == [4, 7]
    await app.stop()


def test_the_manager_pushes_only_what_differs(tmp_path: Path) -> None:
    path = tmp_path / "zones" / "building.json"
    roster = Roster()
    sent: list[tuple[str, dict[str, Any]]] = []
    dist = ZoneDistributor(path, "building", 0.5, roster, lambda r, c: sent.append((r, c)),
                           lambda k, d: None)

    def hear(name: str, digest: str, now: float, map_name: str = "building") -> None:
        roster.heard(name, "status", {"zones": {"map": map_name, "digest": digest}}, now)

    hear("a", "x", 100.0)
    assert dist.check(100.0, 5.0) == []               # no zone file yet: nothing is pushed
    store = ZoneStore(path, "building", 0.5)
    store.add("Stairs", "keepout", KEEPOUT["polygon"])
    assert dist.reload() and not dist.reload()
    hear("a", "x", 101.0)
    hear("b", dist.digest, 101.0)                     # already has them
    hear("c", "x", 101.0, map_name="other")           # another map
    assert dist.check(101.0, 5.0) == ["a"]
    assert sent[-1][1]["action"] == "set_zones" and sent[-1][1]["zones"][0]["name"] == "Stairs"
    assert dist.check(105.0, 5.0) == []               # not again within RESEND_S
    hear("a", "x", 112.0)
    assert dist.check(112.0, 5.0) == ["a"]            # still different: asked again
    hear("a", dist.digest, 113.0)
    assert dist.check(130.0, 5.0) == []
