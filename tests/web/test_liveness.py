"""Health that cannot lie: every part has an age, goes stale when silent, a crashed task is an
error whatever it said last, counters are explained and shown as rates."""

from __future__ import annotations

from typing import Any

import numpy as np

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import DriverHealth, Event, LaserScan, Path, Twist
from curio.core.topics import CMD_VEL_NAV, PLAN, SCAN
from curio.web.liveness import Liveness, counter_info


def scan(stamp: float) -> LaserScan:
    return LaserScan(stamp, -1.0, 0.5, 0.1, 10.0, np.ones(5, dtype=np.float32))


def entry(live: Liveness, name: str) -> dict[str, Any]:
    return next(e for e in live.entries() if e["name"] == name)


async def test_a_silent_part_goes_stale_with_its_age(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    states = {"sim.lidar": "running", "navigator": "running", "behaviour": "running"}
    live = Liveness(cfg, bus, clock, lambda: dict(states))
    live.sample()
    for _ in range(10):  # 10 Hz for a second
        bus.publish(SCAN, scan(clock.now()))
        await clock.advance(0.1)
    live.sample()
    lidar = entry(live, "lidar")
    assert lidar["state"] == "ok" and lidar["age_s"] == 0.1
    assert lidar["rate"] == 10.0 and lidar["what"] == "scans"
    await clock.advance(3.0)  # the lidar stops
    lidar = entry(live, "lidar")
    assert lidar["state"] == "stale" and lidar["age_s"] >= 3.0
    assert lidar["message"] == "stale: last scan 3 s ago"
    states["sim.lidar"] = "crashed: RuntimeError('serial port gone')"
    lidar = entry(live, "lidar")
    assert lidar["state"] == "error" and "serial port gone" in lidar["message"]
    names = [e["name"] for e in live.entries()]
    assert {"planner", "navigator", "behaviour tree", "costmap"}.isdisjoint(names) is False
    assert "ekf" not in names  # not configured in this app: its task is absent


async def test_planner_and_navigator_are_judged_while_a_goal_is_active(
        cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    live = Liveness(cfg, bus, clock, lambda: {"navigator": "running"})
    assert entry(live, "planner")["state"] == "idle"
    live.on_event(Event(clock.now(), "nav.goal_accepted", {"goal_id": 1, "goal": [[1, 0]]}))
    await clock.advance(1.0)
    assert entry(live, "planner")["state"] == "starting"
    await clock.advance(20.0)
    planner = entry(live, "planner")
    assert planner["state"] == "error"
    assert planner["message"] == "no plan for 21 s since the goal was given"
    bus.publish(PLAN, Path(clock.now(), (Pose2D(0, 0), Pose2D(1, 0))))
    bus.publish(CMD_VEL_NAV, Twist(clock.now(), 0.2, 0.0))
    assert entry(live, "planner")["state"] == "ok"
    assert entry(live, "navigator")["state"] == "ok"
    await clock.advance(2.0)
    assert entry(live, "navigator")["state"] == "stale"
    live.on_event(Event(clock.now(), "nav.goal_succeeded", {"goal_id": 1}))
    navigator = entry(live, "navigator")
    assert navigator["state"] == "idle" and "last velocity command 2 s ago" in \
        navigator["message"]


async def test_reports_go_stale_and_counters_become_rates(cfg: Config, bus: Bus) -> None:
    clock = SimClock()
    live = Liveness(cfg, bus, clock, lambda: {"behaviour": "running", "safety": "running"})
    live.on_report(DriverHealth(0.0, "behaviour", "ok", counters={"ticks": 10.0}))
    live.on_report(DriverHealth(1.0, "behaviour", "ok", counters={"ticks": 12.0}))
    live.on_report(DriverHealth(1.0, "safety", "ok", counters={
        "cycles": 20.0, "out_linear_mps": 0.25}))
    live.on_report(DriverHealth(2.0, "safety", "ok", counters={
        "cycles": 40.0, "out_linear_mps": 0.3}))
    await clock.advance(2.0)
    tree = entry(live, "behaviour tree")
    assert tree["state"] == "ok" and tree["age_s"] == 1.0
    (ticks,) = tree["counters"]
    assert (ticks["label"], ticks["rate_per_s"], ticks["value"]) == ("ticks", 2.0, 12.0)
    safety = {c["key"]: c for c in entry(live, "safety")["counters"]}
    assert safety["cycles"]["rate_per_s"] == 20.0 and safety["cycles"]["kind"] == "total"
    assert safety["out_linear_mps"]["kind"] == "gauge" and \
        safety["out_linear_mps"]["unit"] == "m/s" and "rate_per_s" not in safety["out_linear_mps"]
    await clock.advance(5.0)  # the tree stops reporting
    tree = entry(live, "behaviour tree")
    assert tree["state"] == "stale" and tree["age_s"] == 6.0
    assert "no report for 6 s (last said ok)" in tree["message"]
    live.on_report(DriverHealth(7.0, "mystery", "degraded", "?", {"widgets": 3.0}))
    mystery = entry(live, "mystery")  # an unknown reporter is listed too
    assert mystery["state"] == "degraded" and mystery["age_s"] == 0.0


def test_counter_names_are_explained() -> None:
    assert counter_info("crc_errors") == ("frames with a bad checksum", "total", "")
    assert counter_info("battery_v") == ("battery", "gauge", "V")
    assert counter_info("calibration_sys") == ("calibration sys", "gauge", "")
    assert counter_info("frobnications") == ("frobnications", "total", "")
