"""The people wiring: with ``people.aware`` the tracker filters the costmap's marks and the
controller has the people stage; the baseline (aware off) leaves navigation as it was."""

from __future__ import annotations

import pytest

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.parts import Parts
from curio.core.topics import make_bus
from curio.nav.wiring import build_navigation
from curio.people.wiring import build_people
from curio.robot import RobotModel
from tests.unit.test_controller import open_grid


@pytest.mark.parametrize("aware", [True, False])
def test_aware_hooks_the_tracker_into_navigation(cfg: Config, aware: bool) -> None:
    cfg = cfg.model_copy(update={"people": cfg.people.model_copy(update={"aware": aware})})
    bus, clock, parts = make_bus(), SimClock(), Parts()
    robot = RobotModel.from_config(cfg.robot)
    grid = open_grid()
    nav = build_navigation(cfg, bus, clock, parts, robot, grid)
    people = build_people(cfg, bus, clock, parts, robot, nav, grid)
    assert people is not None
    assert nav.costmap_node is not None
    if aware:
        assert nav.costmap_node.mark_filter is people.node
        assert nav.controller.people is people.stage is not None
        assert people.guide is not None
    else:
        assert nav.costmap_node.mark_filter is None
        assert nav.controller.people is None
        assert people.stage is None and people.guide is None


def test_tracking_off_builds_nothing(cfg: Config) -> None:
    cfg = cfg.model_copy(update={"people": cfg.people.model_copy(update={"tracking": False})})
    bus, clock, parts = make_bus(), SimClock(), Parts()
    robot = RobotModel.from_config(cfg.robot)
    grid = open_grid()
    nav = build_navigation(cfg, bus, clock, parts, robot, grid)
    assert build_people(cfg, bus, clock, parts, robot, nav, grid) is None
    assert nav.costmap_node is not None and nav.costmap_node.mark_filter is None
    assert nav.controller.people is None
