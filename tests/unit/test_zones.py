"""Zones: validation, the per-map store, masks and Nav2 export, the guard, the costmap layer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from curio.core.config import Config, ZonesConfig
from curio.core.geometry import Pose2D
from curio.core.messages import PoseWithCovariance
from curio.core.topics import POSE, ZONES, make_bus
from curio.estimation.maps import OccupancyGrid, load_map
from curio.nav.api import NoPathError
from curio.nav.costmap import Costmap
from curio.nav.costs import LETHAL
from curio.nav.planner import GlobalPlanner
from curio.robot import RobotModel
from curio.zones.guard import SPEED_MARGIN, ZoneGuard
from curio.zones.masks import export_nav2_masks, keepout_mask
from curio.zones.model import ZoneError, make_zone
from curio.zones.service import ZoneService
from curio.zones.store import ZoneFileError, ZoneStore

from .bt_fakes import ManualClock

SQUARE = [[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]]


@pytest.mark.parametrize(("kind", "polygon", "limit", "message"), [
    ("wall", SQUARE, None, "kind must be 'keepout' or 'speed'"),
    ("keepout", SQUARE[:2], None, "needs 3 to 200 points"),
    ("keepout", [[0, 0], [1, 1], [1, 0], [0, 1]], None, "edges cross"),
    ("keepout", [[0, 0], [1, 1], [2, 2]], None, "in a line"),
    ("keepout", [[0, 0], [1, "a"], [2, 0]], None, "point 1"),
    ("speed", SQUARE, None, "speed_limit_mps between 0 and 0.37"),
    ("speed", SQUARE, 0.5, "speed_limit_mps between 0 and 0.37"),
    ("keepout", SQUARE, 0.1, "a keep-out zone has no speed limit"),
])
def test_bad_zones_are_refused_with_a_sentence(kind: str, polygon: list[list[float]],
                                               limit: float | None, message: str) -> None:
    with pytest.raises(ZoneError, match=message):
        make_zone(1, "Z", kind, polygon, limit, 0.37)


def test_store_persists_never_reuses_ids_and_refuses_stale_edits(tmp_path: Path) -> None:
    path = tmp_path / "zones" / "building.json"
    store = ZoneStore(path, "building", 0.37)
    a = store.add("Stairs", "keepout", SQUARE)
    b = store.add("Corridor", "speed", [[0, 0], [3, 0], [3, 1], [0, 1]], 0.15)
    store.delete(a.id)
    c = store.add("Lift", "keepout", SQUARE)
    assert (a.id, b.id, c.id) == (1, 2, 3)
    with pytest.raises(ZoneError, match="changed meanwhile"):
        store.update(b.id, expect_revision=1, name="x")
    store.update(b.id, expect_revision=store.revision, speed_limit_mps=0.2)
    again = ZoneStore(path, "building", 0.37)
    assert [z.to_json() for z in again.list_zones()] == [z.to_json()
                                                         for z in store.list_zones()]
    assert again.get(2).speed_limit_mps == 0.2
    assert json.loads(path.read_text())["version"] == 1
    path.write_text("{not json")
    with pytest.raises(ZoneFileError, match=r"building\.json"):
        ZoneStore(path, "building", 0.37)


def _grid(w: int = 80, h: int = 60) -> OccupancyGrid:
    data = np.zeros((h, w), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0), name="box")


def test_masks_and_the_nav2_export(tmp_path: Path) -> None:
    grid = _grid()
    zones = [make_zone(1, "K", "keepout", SQUARE, None, 0.37),
             make_zone(2, "S", "speed", [[2.5, 0.5], [3.5, 0.5], [3.5, 2.5], [2.5, 2.5]], 0.15,
                       0.37)]
    mask = keepout_mask(zones, grid.resolution_m, grid.origin, (60, 80), 0.05)
    assert mask[30, 30] and not mask[30, 45]  # (1.5, 1.5) inside, (2.25, 1.5) outside
    assert mask[30, 18] and not mask[30, 17]  # grown by the margin: 0.90..0.95 m touches
    files = export_nav2_masks(zones, grid, tmp_path, "box")
    assert {f.name for f in files} == {"box_keepout.yaml", "box_keepout.pgm", "box_speed.yaml",
                                       "box_speed.pgm", "box_filters.yaml"}
    keep = load_map(tmp_path / "box_keepout.yaml")
    assert keep.data[30, 30] == 100 and keep.data[30, 45] == 0
    speed = load_map(tmp_path / "box_speed.yaml")
    assert speed.data[30, 60] == 15 and speed.data[30, 30] == 0  # 0.15 m/s = 15 × 0.01
    assert "type: 2" in (tmp_path / "box_filters.yaml").read_text()


def test_guard_slows_before_a_speed_zone_and_stops_before_a_keepout() -> None:
    robot = RobotModel.from_config(Config().robot)
    guard = ZoneGuard(robot, ZonesConfig(speed_margin_m=0.25, lookahead_s=1.5))
    guard.set_zones([make_zone(1, "K", "keepout", [[3, -1], [4, -1], [4, 1], [3, 1]], None,
                               0.37),
                     make_zone(2, "S", "speed", [[0, 3], [2, 3], [2, 4], [0, 4]], 0.12, 0.37)])
    assert guard.speed_limit_at(Pose2D(1.0, 2.5, 0.0)) == pytest.approx(0.12 * SPEED_MARGIN)
    assert math.isinf(guard.speed_limit_at(Pose2D(1.0, 2.0, 0.0)))  # 0.69 m away
    # Heading for the keep-out zone 0.4 m ahead of the footprint: stop before it.
    factor = guard.keepout_factor(Pose2D(2.27, 0.0, 0.0), 0.3, 0.0)
    assert 0.0 < factor < 1.0 and factor * 0.3 * 1.5 <= 0.4 + 0.05
    assert guard.keepout_factor(Pose2D(2.27, 0.0, math.pi), 0.3, 0.0) == 1.0  # away
    assert guard.keepout_factor(Pose2D(3.5, 0.0, 0.0), 0.3, 0.0) == 1.0  # inside: may leave


def test_keepout_cells_are_lethal_and_the_planner_goes_around() -> None:
    data = np.zeros((60, 120), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    grid = OccupancyGrid(data, 0.05, Pose2D(), name="hall")
    cfg = Config()
    costmap = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    planner = GlobalPlanner(cfg.nav.planner)
    start, goal = Pose2D(1.0, 1.5, 0.0), Pose2D(5.0, 1.5, 0.0)
    straight = planner.plan(start, goal, costmap.costs(), 0.05, Pose2D())
    wall = make_zone(1, "K", "keepout", [[2.8, 0.0], [3.2, 0.0], [3.2, 2.2], [2.8, 2.2]], None,
                     0.37)
    costmap.set_keepout(keepout_mask([wall], 0.05, Pose2D(), costmap.shape, 0.05))
    assert costmap.cost_at(3.0, 1.0) == LETHAL
    around = planner.plan(start, goal, costmap.costs(), 0.05, Pose2D())
    assert min(p.y for p in straight) > 1.4 and max(p.y for p in around) > 2.2
    full = make_zone(2, "K", "keepout", [[2.8, 0.0], [3.2, 0.0], [3.2, 3.0], [2.8, 3.0]], None,
                     0.37)
    costmap.set_keepout(keepout_mask([full], 0.05, Pose2D(), costmap.shape, 0.05))
    with pytest.raises(NoPathError):
        planner.plan(start, goal, costmap.costs(), 0.05, Pose2D())


def test_service_refuses_a_keepout_over_the_rover_or_home(tmp_path: Path) -> None:
    cfg = Config(data_dir=str(tmp_path))
    bus = make_bus()
    robot = RobotModel.from_config(cfg.robot)
    store = ZoneStore(tmp_path / "z.json", "box", 0.37)
    service = ZoneService(cfg, bus, ManualClock(), store, _grid(), ZoneGuard(robot, cfg.zones),  # type: ignore[arg-type]
                          home=lambda: Pose2D(3.0, 2.0, 0.0))
    bus.publish(POSE, PoseWithCovariance(0.0, Pose2D(1.5, 1.5, 0.0)))
    with pytest.raises(ZoneError, match="covers the rover"):
        service.add({"name": "K", "kind": "keepout", "polygon": SQUARE})
    with pytest.raises(ZoneError, match="home and dock"):
        service.add({"name": "K", "kind": "keepout",
                     "polygon": [[2.8, 1.8], [3.2, 1.8], [3.2, 2.2], [2.8, 2.2]]})
    zone = service.add({"name": "S", "kind": "speed", "polygon": SQUARE,
                        "speed_limit_mps": 0.1})
    assert zone.id == 1
    published = bus.latest(ZONES)
    assert published is not None and published.detail["zones"][0]["name"] == "S"
