"""Simulator wiring: the world, rover physics and simulated sensors (owner: simulator).

``build_sim`` builds them when the ``drivers.mode`` table (:mod:`curio.drivers.modes`) has a
device emulated or simulated, i.e. in ``sim`` and ``emulated`` mode (None in ``real`` mode):

* both modes: the :class:`~curio.sim.world.World`, a physics loop at
  ``cfg.sim.physics_rate_hz`` that also publishes ``/ground_truth`` (``map``, every physics
  step, ≥ 20 Hz) and the world's events (``collision``, ``door``) on ``/events``;
* ``sim`` mode only (the devices the table puts on the simulator):
  :class:`~curio.sim.base.SimBase` (the base: ``/cmd_vel`` → kinematics →
  ``/servo_cmd`` → the world, with the 0.5 s command timeout and a halt hook) and the sensor
  publishers ``/scan`` (``cfg.sim.lidar_rate_hz``), ``/imu`` (``cfg.sim.imu_rate_hz``),
  ``/wheels`` (``cfg.sim.wheel_feedback_rate_hz``) and ``/battery`` (1 Hz). In ``emulated`` mode the
  byte-exact device emulators pull from the world instead.
* both modes: ``/health`` (name ``simulator``, 1 Hz) with collision, step and scan counters;
* with simulated visitors (``sim.crowd.visitors``): ``/people/ground_truth`` at the lidar rate;
  the visitors hear the rover's ``people.excuse_me`` events and follow it while a guided tour
  runs (``path.started`` / ``path.finished`` of the tour route).
"""

from __future__ import annotations

from dataclasses import dataclass

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import BatteryState, DriverHealth, Event, Odometry, WheelEncoders
from curio.core.parts import Part, Parts
from curio.core.topics import (
    BATTERY,
    EVENTS,
    GROUND_TRUTH,
    HEALTH,
    IMU,
    PEOPLE_TRUTH,
    SCAN,
    WHEELS,
)
from curio.drivers.modes import driver_mode
from curio.robot import RobotModel
from curio.sim.base import SimBase
from curio.sim.world import World

__all__ = ["SimParts", "Simulator", "build_sim"]

LOW_BATTERY_V = 6.6
TOUR_ROUTE_ID = -1  # the behaviour tree's route id of a guided tour (curio.bt.follower)


class Simulator:
    """Runs the world's physics on the clock and publishes ground truth, events and (in
    ``sim`` mode) the sensors."""

    def __init__(self, cfg: Config, bus: Bus, clock: Clock, world: World,
                 publish_sensors: bool) -> None:
        self.cfg = cfg
        self.bus = bus
        self.clock = clock
        self.world = world
        self.publish_sensors = publish_sensors
        self.physics_steps = 0
        self.scans = 0

    def _publish_truth(self, stamp: float) -> None:
        v, w = self.world.truth_twist
        self.bus.publish(GROUND_TRUTH, Odometry(stamp, self.world.truth_pose, v, w,
                                                covariance=(0.0,) * 9, frame_id="map"))
        for kind, detail in self.world.pop_events():
            self.bus.publish(EVENTS, Event(stamp, kind, detail))

    async def run_physics(self) -> None:
        """Step the world at ``physics_rate_hz`` and publish ``/ground_truth``."""
        dt = 1.0 / self.cfg.sim.physics_rate_hz
        self._publish_truth(self.clock.now())
        async for t in self.clock.every(dt, phase_s=dt):
            self.world.step(dt)
            self.physics_steps += 1
            self._publish_truth(t)

    async def run_scan(self) -> None:
        """Publish one lidar revolution per ``1 / lidar_rate_hz``."""
        async for t in self.clock.every(1.0 / self.cfg.sim.lidar_rate_hz, phase_s=0.005):
            self.bus.publish(SCAN, self.world.cast_scan(t))
            self.scans += 1

    async def run_imu(self) -> None:
        """Publish BNO055 samples at ``imu_rate_hz``, each stamped at its own sample time.

        The world only moves at physics steps, so the samples between two steps see the same
        state. When ``imu_rate_hz`` is a whole multiple ``n`` of ``physics_rate_hz``, the
        ``n`` samples of one physics period are handed over together, at the last one's time
        (the first arrives ``(n - 1) / imu_rate_hz`` late, like a driver reading the sensor's
        FIFO): the same messages, with the loop woken once instead of ``n`` times. The EKF, the
        one reader, drains its queue at ``ekf.rate_hz``; at or below the physics rate it sees
        exactly the same samples at each of its ticks.
        """
        period_s = 1.0 / self.cfg.sim.imu_rate_hz
        ratio = self.cfg.sim.imu_rate_hz / self.cfg.sim.physics_rate_hz
        per_wake = round(ratio) if ratio >= 1.0 and abs(ratio - round(ratio)) < 1e-9 else 1
        stamp = self.clock.now() + 0.001
        async for _ in self.clock.every(per_wake * period_s,
                                        phase_s=0.001 + (per_wake - 1) * period_s):
            for _ in range(per_wake):
                self.bus.publish(IMU, self.world.imu_sample(stamp))
                stamp += period_s

    async def run_wheels(self) -> None:
        """Publish the wheel servo positions at ``wheel_feedback_rate_hz``."""
        period = 1.0 / self.cfg.sim.wheel_feedback_rate_hz
        async for t in self.clock.every(period, phase_s=0.002):
            p = self.world.wheel_positions()
            self.bus.publish(WHEELS, WheelEncoders(t, (p[0], p[1], p[2], p[3], p[4], p[5])))

    async def run_battery(self) -> None:
        """Publish the servo pack voltage (``sim`` mode) and the simulator's health, 1 Hz."""
        async for t in self.clock.every(1.0, phase_s=0.003):
            if self.publish_sensors:
                volts = self.world.battery_voltage()
                self.bus.publish(BATTERY, BatteryState(t, volts, low=volts < LOW_BATTERY_V,
                                                       charger_v=self.world.charger_voltage()))
            self.bus.publish(HEALTH, DriverHealth(t, "simulator", "ok", counters={
                "collisions": float(self.world.collisions),
                "physics_steps": float(self.physics_steps),
                "scans": float(self.scans),
                "in_contact": float(self.world.in_contact)}))


    async def run_crowd(self) -> None:
        """Publish the visitors' ground truth at the lidar rate (just after each scan) and
        pass them what they hear: "Excuse me", a guided tour starting or ending."""
        crowd = self.world.crowd
        if crowd is None:
            return
        events = self.bus.subscribe(EVENTS)
        try:
            async for t in self.clock.every(1.0 / self.cfg.sim.lidar_rate_hz, phase_s=0.006):
                for ev in events.drain():
                    if ev.kind == "people.excuse_me":
                        crowd.hear_excuse_me(self.world.truth_pose)
                    elif ev.kind.startswith("path.") and ev.detail.get("path_id") == \
                            TOUR_ROUTE_ID:
                        crowd.following = ev.kind == "path.started"
                self.bus.publish(PEOPLE_TRUTH, self.world.people_truth(t))
        finally:
            events.close()


@dataclass(frozen=True)
class SimParts:
    """The simulator's objects; ``base`` only in ``sim`` mode (the emulators drive the world in
    ``emulated`` mode)."""

    world: World
    simulator: Simulator
    base: SimBase | None


def build_sim(cfg: Config, bus: Bus, clock: Clock, parts: Parts,
              robot: RobotModel) -> SimParts | None:
    """Construct the world and simulator parts (when the ``drivers.mode`` table has a device
    emulated or simulated; else None) and the simulator's stand-ins for the simulated devices."""
    mode = driver_mode(cfg)
    if not mode.world:
        return None
    world = World.from_config(cfg, robot)
    sim_base = mode.base == "simulator"
    simulator = Simulator(cfg, bus, clock, world, publish_sensors=sim_base)
    parts.add(Part("sim.physics", run=simulator.run_physics))
    parts.add(Part("sim.battery", run=simulator.run_battery))
    if world.crowd is not None:
        parts.add(Part("sim.crowd", run=simulator.run_crowd))
    base = None
    if sim_base:
        base = SimBase(cfg, bus, clock, world, robot)
        parts.add(Part("sim.base", run=base.run, close=base.close))
        parts.add(Part("sim.base.watchdog", run=base.run_watchdog))
        parts.add_halt_hook(base.halt)
    if mode.lidar == "simulator":
        parts.add(Part("sim.lidar", run=simulator.run_scan))
    if mode.imu == "simulator":
        parts.add(Part("sim.imu", run=simulator.run_imu))
    if sim_base:
        parts.add(Part("sim.wheels", run=simulator.run_wheels))  # the base's wheel feedback
    return SimParts(world, simulator, base)
