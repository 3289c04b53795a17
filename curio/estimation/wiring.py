"""Estimation wiring: map server, EKF (``odom``) and localisation (``map`` → ``odom``).

Topics (see ``curio/core/topics.py``):

* ``MAP`` (latched): the navigation map, loaded from ``localization.map_yaml`` or ``sim.world``.
* ``ODOM``: fused odometry, ``odom`` → ``base_link`` (the EKF; wheel odometry passed through when
  ``ekf.enabled`` is false).
* ``POSE`` (latched): ``base_link`` in ``map`` = ``MAP_TO_ODOM`` ∘ ``ODOM``, published at the
  odometry rate with the odometry stamp so consumers get smooth, time-consistent poses.
* ``MAP_TO_ODOM`` (latched) and ``LOCALIZATION`` (latched): the correction and its quality.

With ``localization.mode = "map"`` the rover maps a new building instead
(:mod:`curio.estimation.mapping`): ``MAP`` is republished as it grows and the map is saved to
``data_dir/localization.mapping_out`` at shutdown. ``app.localizer`` is then the mapping node.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import (
    GridMessage,
    LocalizationStatus,
    Odometry,
    PoseWithCovariance,
    Transform,
)
from curio.core.topics import LOCALIZATION, MAP, MAP_TO_ODOM, ODOM, POSE, WHEEL_ODOM
from curio.estimation.maps import OccupancyGrid, load_map

if TYPE_CHECKING:
    from curio.app import App
    from curio.core.config import Config

__all__ = ["MapServer", "OdomRelay", "build_estimation", "map_path", "start_pose"]

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


def start_pose(cfg: Config) -> Pose2D:
    """The initial pose of ``base_link`` in ``map``: ``sim.start`` (simulator) or ``robot.home``."""
    if cfg.drivers.mode != "real" and cfg.sim.start is not None:
        return Pose2D(*cfg.sim.start)
    return Pose2D(*cfg.robot.home)


class OdomRelay:
    """Pass wheel odometry through as ``ODOM`` and compose ``POSE`` with a fixed ``map → odom``.

    Used when both the EKF and localisation are disabled (pure dead reckoning); ``map → odom``
    is set from the start pose at the first odometry message.
    """

    def __init__(self, bus: Bus, start: Pose2D, *, relay_odom: bool, compose_pose: bool) -> None:
        self._bus = bus
        self._start = start
        self._relay_odom = relay_odom
        self._compose_pose = compose_pose
        self.map_to_odom: Pose2D | None = None

    def on_odom(self, odom: Odometry) -> None:
        """Handle one wheel-odometry message."""
        if self._relay_odom:
            self._bus.publish(ODOM, odom)
        if not self._compose_pose:
            return
        if self.map_to_odom is None:
            self.map_to_odom = self._start @ odom.pose.inverse()
            self._bus.publish(MAP_TO_ODOM, Transform(odom.stamp, self.map_to_odom))
            self._bus.publish(LOCALIZATION, LocalizationStatus(odom.stamp, "off"))
        self._bus.publish(POSE, PoseWithCovariance(odom.stamp, self.map_to_odom @ odom.pose,
                                                   odom.covariance))

    async def run(self) -> None:
        """Relay every odometry message (``WHEEL_ODOM``, or ``ODOM`` when only composing)."""
        sub = self._bus.subscribe(WHEEL_ODOM if self._relay_odom else ODOM, maxsize=8)
        try:
            async for odom in sub:
                self.on_odom(odom)
        finally:
            sub.close()


def build_estimation(app: App) -> None:
    """Load the map, then build the EKF and the localiser and register them on ``app``."""
    from curio.app import Part

    cfg = app.cfg
    start = start_pose(cfg)
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
    app.map_server = MapServer(app.bus, app.clock, grid)
    app.map_server.publish()

    relay_odom = not cfg.ekf.enabled
    compose_pose = not cfg.localization.enabled
    if cfg.ekf.enabled:
        from curio.estimation.ekf import build_ekf_part

        app.ekf = build_ekf_part(app)
    if mapping:
        from curio.estimation.mapping import build_mapping_part

        app.localizer = build_mapping_part(app, start, cfg.data_path(cfg.localization.mapping_out))
    elif cfg.localization.enabled:
        from curio.estimation.localization import build_localizer_part

        app.localizer = build_localizer_part(app, grid, start)
    if relay_odom or compose_pose:
        relay = OdomRelay(app.bus, start, relay_odom=relay_odom, compose_pose=compose_pose)
        app.add(Part("odom_relay", run=relay.run))
