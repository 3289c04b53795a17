"""Localisation reports its state on ``/health`` (found by ``curio soak``: a kidnapped rover's
lost localisation showed nowhere in the health panel nor, so, in the event log)."""

from __future__ import annotations

from types import SimpleNamespace

from curio.core.clock import SimClock
from curio.core.geometry import Pose2D
from curio.core.topics import HEALTH, make_bus
from curio.estimation.localization import LocalizerNode, localization_health


def test_states_map_to_health_with_what_to_do() -> None:
    assert localization_health(1.0, "ok", 0.05).state == "ok"
    uncertain = localization_health(1.0, "uncertain", 0.8)
    assert uncertain.state == "degraded" and "0.80 m" in uncertain.message
    lost = localization_health(1.0, "lost", 3.0)
    assert lost.state == "error" and "set its position" in lost.message


def test_a_state_change_is_published_at_once_and_repeated_every_second() -> None:
    bus = make_bus()
    health = bus.subscribe(HEALTH, maxsize=100)
    loc = SimpleNamespace(state="ok", particles=[0] * 10, std_xy_m=0.05, std_yaw_rad=0.01)
    node = LocalizerNode(bus, SimClock(), loc, Pose2D())  # type: ignore[arg-type]
    for k in range(10):  # ten scans in a second: one report
        node.publish_status(k * 0.1)
    assert [h.state for h in health.drain()] == ["ok"]
    loc.state = "lost"
    node.publish_status(1.05)
    assert [h.state for h in health.drain()] == ["error"]
    node.publish_status(2.1)
    assert [h.name for h in health.drain()] == ["localization"]
