"""Estimation wiring: map server, EKF (``odom``) and localisation (``map`` → ``odom``).

Topics (see ``curio/core/topics.py``):

* ``MAP`` (latched): the navigation map, loaded from ``localization.map_yaml`` or ``sim.world``.
* ``ODOM``: fused odometry, ``odom`` → ``base_link`` (the EKF; wheel odometry passed through when
  ``ekf.enabled`` is false).
* ``POSE`` (latched): ``base_link`` in ``map`` = ``MAP_TO_ODOM`` ∘ ``ODOM``, published at the
  odometry rate with the odometry stamp so consumers get smooth, time-consistent poses.
* ``MAP_TO_ODOM`` (latched) and ``LOCALIZATION`` (latched): the correction and its quality.

The rover starts where the last run left it (:mod:`curio.estimation.last_pose`,
``localization.resume_last_pose``): the localised pose is kept in ``data_dir/last_pose.json``.

With ``localization.mode = "map"`` the rover maps a new building instead
(:mod:`curio.estimation.mapping`): ``MAP`` is republished as it grows and the map is saved to
``data_dir/localization.mapping_out`` at shutdown; the result's ``localizer`` is then the
mapping node.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import (
    GridMessage,
    LocalizationStatus,
    Odometry,
)
from curio.core.parts import Part, Parts
from curio.core.topics import LOCALIZATION, MAP, ODOM, WHEEL_ODOM
from curio.drivers.modes import driver_mode
from curio.estimation.correction import MapOdomPublisher
from curio.estimation.ekf import EkfNode, OdomEkf
from curio.estimation.last_pose import LAST_POSE_FILE, LastPoseKeeper, load_last_pose
from curio.estimation.localization import Localizer, LocalizerNode
from curio.estimation.mapping import MapperParams, MappingNode
from curio.estimation.maps import OccupancyGrid, load_map, save_map
from curio.robot import RobotModel

__all__ = [
    "Estimation",
    "Localiser",
    "MapServer",
    "OdomRelay",
    "build_estimation",
    "map_name",
    "map_path",
    "start_pose",
]

log = logging.getLogger("curio.estimation.wiring")


class MapServer:
    """Holds the navigation map and publishes it latched on ``MAP``.

    Attributes:
        grid: the occupancy grid in ``map``.
        version: bumped by :meth:`set_grid` (the dashboard refetches on a new version).
    """

    def __init__(self, bus: Bus, clock: Clock, grid: OccupancyGrid) -> None:
        self._bus = bus
        self._clock = clock
        self.grid = grid
        self.version = 0

    def publish(self) -> None:
        """Publish the current grid on ``MAP``."""
        self._bus.publish(MAP, GridMessage(self._clock.now(), self.grid.data,
                                           self.grid.resolution_m, self.grid.origin,
                                           version=self.version, kind="map"))

    def set_grid(self, grid: OccupancyGrid) -> None:
        """Replace the map (e.g. after mapping) and republish it."""
        self.grid = grid
        self.version += 1
        self.publish()


def map_path(cfg: Config) -> str:
    """The map YAML the rover navigates in: ``localization.map_yaml`` or else ``sim.world``."""
    chosen = cfg.localization.map_yaml or cfg.sim.world
    return str(cfg.resolve(chosen))


def map_name(cfg: Config) -> str:
    """The name of the map the rover navigates in: its YAML file's stem (the map library's
    name, the zones' file, what the fleet compares)."""
    return Path(map_path(cfg)).stem


def start_pose(cfg: Config, robot: RobotModel) -> Pose2D:
    """The initial pose of ``base_link`` in ``map``: where the last run left the rover
    (``data_dir/last_pose.json``, with ``localization.resume_last_pose``), else ``sim.start``
    (simulator) or the robot's home."""
    if cfg.localization.resume_last_pose:
        last = load_last_pose(cfg.data_path(LAST_POSE_FILE))
        if last is not None:
            return last
    if driver_mode(cfg).world and cfg.sim.start is not None:
        return Pose2D(*cfg.sim.start)
    return robot.home


class OdomRelay(MapOdomPublisher):
    """Pass wheel odometry through as ``ODOM`` and compose ``POSE`` with a fixed ``map → odom``.

    Used when both the EKF and localisation are disabled (pure dead reckoning); ``map → odom``
    is set from the start pose at the first odometry message.
    """

    def __init__(self, bus: Bus, start: Pose2D, *, relay_odom: bool, compose_pose: bool) -> None:
        super().__init__(bus)
        self._start = start
        self._relay_odom = relay_odom
        self._compose_pose = compose_pose

    def on_odom(self, odom: Odometry) -> None:
        """Handle one wheel-odometry message."""
        if self._relay_odom:
            self.bus.publish(ODOM, odom)
        if self._compose_pose:
            super().on_odom(odom)

    def initial_pose(self) -> Pose2D:
        """The start pose."""
        return self._start

    def publish_status(self, stamp: float) -> None:
        """``LOCALIZATION``: ``off``."""
        self.bus.publish(LOCALIZATION, LocalizationStatus(stamp, "off"))

    def pose_covariance(self, odom: Odometry) -> tuple[float, ...]:
        """The odometry's own covariance."""
        return odom.covariance

    async def run(self) -> None:
        """Relay every odometry message (``WHEEL_ODOM``, or ``ODOM`` when only composing)."""
        sub = self.bus.subscribe(WHEEL_ODOM if self._relay_odom else ODOM, maxsize=8)
        try:
            async for odom in sub:
                self.on_odom(odom)
        finally:
            sub.close()


Localiser = LocalizerNode | MappingNode


@dataclass(frozen=True)
class Estimation:
    """The estimation subsystem's objects.

    Attributes:
        map_server: holds and publishes the navigation map.
        ekf: the odometry EKF (None when ``ekf.enabled`` is false).
        localizer: the localiser, or the mapping node in ``localization.mode = "map"``; None
            when localisation is off.
    """

    map_server: MapServer
    ekf: EkfNode | None
    localizer: Localiser | None


def build_estimation(cfg: Config, bus: Bus, clock: Clock, parts: Parts,
                     robot: RobotModel,
                     amend_map: Callable[[OccupancyGrid], OccupancyGrid] | None = None
                     ) -> Estimation:
    """Load the map, then build the EKF and the localiser (or mapper) and register them.

    ``amend_map`` changes the loaded map before anything uses it (the dock drawn at home).
    """
    start = start_pose(cfg, robot)
    mapping = cfg.localization.enabled and cfg.localization.mode == "map"
    if mapping:
        # A new building: start from an unknown 20 m square around the start pose; the mapper
        # replaces it as it goes.
        res = 0.05
        size = round(20.0 / res)
        grid = OccupancyGrid(np.full((size, size), -1, dtype=np.int8), res,
                             Pose2D(start.x - 10.0, start.y - 10.0, 0.0), name="mapping")
    else:
        grid = load_map(map_path(cfg))
        if amend_map is not None:
            grid = amend_map(grid)
    map_server = MapServer(bus, clock, grid)
    map_server.publish()
    ekf = None
    if cfg.ekf.enabled:
        ekf = EkfNode(bus, clock, OdomEkf(cfg.ekf, robot.imu_in_base.yaw))
        parts.add(Part("ekf", run=ekf.run))
    localizer: Localiser | None = None
    if mapping:
        localizer = _mapping(cfg, bus, clock, parts, robot, start, map_server)
    elif cfg.localization.enabled:
        loc = Localizer(grid, cfg.localization, robot.laser_in_base,
                        seed=cfg.sim.seed * 7919 + 4)
        localizer = LocalizerNode(bus, clock, loc, start)
        parts.add(Part("localization", run=localizer.run))
    if cfg.localization.resume_last_pose:
        keeper = LastPoseKeeper(cfg.data_path(LAST_POSE_FILE), bus, clock)
        parts.add(Part("last_pose", run=keeper.run, close=keeper.close))
    relay_odom = not cfg.ekf.enabled
    compose_pose = not cfg.localization.enabled
    if relay_odom or compose_pose:
        relay = OdomRelay(bus, start, relay_odom=relay_odom, compose_pose=compose_pose)
        parts.add(Part("odom_relay", run=relay.run))
    return Estimation(map_server, ekf, localizer)


def _mapping(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
             start: Pose2D, map_server: MapServer) -> MappingNode:
    """Online mapping (instead of localisation); the map is saved to
    ``data_dir/localization.mapping_out`` at shutdown."""
    out_yaml = cfg.data_path(cfg.localization.mapping_out)
    params = MapperParams(max_range_m=cfg.sim.lidar_range_max_m)
    node = MappingNode(bus, clock, robot.laser_in_base, start, map_server.set_grid, params)

    async def close() -> None:
        grid = await node.finish()
        if grid is not None:
            save_map(grid, out_yaml)
            log.info("map saved to %s", out_yaml)

    parts.add(Part("mapping", run=node.run, close=close))
    return node
