"""Estimation wiring: map server, ODOM and POSE topics on a bus driven by fake wheel odometry."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any

from curio.clock import SimClock
from curio.config import Config
from curio.geometry import Pose2D
from curio.messages import Odometry
from curio.nav.estimation import build_estimation
from curio.topics import LOCALIZATION, MAP, ODOM, POSE, WHEEL_ODOM, make_bus


class FakeApp:
    """The few App attributes the estimation wiring uses."""

    def __init__(self, cfg: Config, clock: SimClock) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus = make_bus()
        self.parts: list[Any] = []
        self.map_server: Any = None
        self.ekf: Any = None
        self.localizer: Any = None
        self.world: Any = None

    def add(self, part: Any) -> None:
        self.parts.append(part)


async def test_relay_publishes_map_odom_and_pose(cfg: Config, shared_maps: Path) -> None:
    world = shared_maps / "tb3_sandbox" / "tb3_sandbox.yaml"
    cfg = cfg.model_copy(update={
        "sim": cfg.sim.model_copy(update={"world": str(world), "start": (1.0, 2.0, math.pi / 2)}),
        "ekf": cfg.ekf.model_copy(update={"enabled": False}),
        "localization": cfg.localization.model_copy(update={"enabled": False}),
    })
    clock = SimClock()
    app = FakeApp(cfg, clock)
    build_estimation(app)  # type: ignore[arg-type]
    assert app.map_server.grid.width == 384
    assert app.bus.latest(MAP) is not None
    tasks = [asyncio.create_task(p.run()) for p in app.parts if p.run is not None]
    await clock.advance(0.01)
    app.bus.publish(WHEEL_ODOM, Odometry(0.0, Pose2D(0.0, 0.0, 0.0)))
    await clock.advance(0.01)
    app.bus.publish(WHEEL_ODOM, Odometry(0.1, Pose2D(1.0, 0.0, 0.0)))
    await clock.advance(0.01)
    pose = app.bus.latest(POSE)
    assert pose is not None and pose.stamp == 0.1
    assert math.isclose(pose.pose.x, 1.0, abs_tol=1e-9)
    assert math.isclose(pose.pose.y, 3.0, abs_tol=1e-9)
    assert app.bus.latest(ODOM) is not None
    status = app.bus.latest(LOCALIZATION)
    assert status is not None and status.state == "off"
    for t in tasks:
        t.cancel()
