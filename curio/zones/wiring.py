"""Zones wiring: the zone service of the navigation map (``build_zones``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid
from curio.robot import RobotModel

from .guard import ZoneGuard
from .service import ZoneService
from .store import ZoneStore

__all__ = ["build_zones", "zone_file"]


def zone_file(cfg: Config, map_name: str) -> Path:
    """``<data_dir>/<zones.directory>/<map name>.json``."""
    return cfg.data_path(cfg.zones.directory) / f"{map_name}.json"


def build_zones(cfg: Config, bus: Bus, clock: Clock, robot: RobotModel, grid: OccupancyGrid,
                map_name: str, *, costmap: Any = None, controller: Any = None,
                safety: Any = None, home: Callable[[], Pose2D] | None = None
                ) -> ZoneService | None:
    """The zone service of the map ``map_name`` (None when ``zones.enabled`` is false);
    hooks its guard into the controller and the safety stage."""
    if not cfg.zones.enabled:
        return None
    store = ZoneStore(zone_file(cfg, map_name), map_name, robot.max_wheel_speed_mps)
    guard = ZoneGuard(robot, cfg.zones, bus)
    if controller is not None:
        controller.speed_limits["speed zone"] = guard.speed_limit_at
    if safety is not None:
        safety.zone_guard = guard
    return ZoneService(cfg, bus, clock, store, grid, guard, costmap, home)
