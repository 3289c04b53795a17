"""Localisation benchmark: tracking accuracy on a long tour, kidnapped-rover recovery, cost.

Drives the simulator directly (world physics, wheel encoders → the real odometry, the BNO055
model, the lidar ray caster; no bus tasks) so that a 15-minute tour takes about a minute:

* **tracking** — the default world (``sim.world``) with the ``cfg.sim.noise`` defaults
  (odometry 5 % scale and 2°/m heading drift, lidar σ 2 cm with dropouts, gyro bias); the rover
  follows a tour through every room with a pure-pursuit controller *on the estimated pose*, for
  ``--extra duration_s=900`` seconds. Figures: position RMSE (m), heading RMSE (deg), maximum
  position error (m) after the first 2 s, and the median / p99 wall time and process CPU time
  of one filter update (a scan with the motion, sensor, scan-matching and resampling steps; the
  CPU time is the fairer figure on a machine shared with other work).
* **kidnap** — for each of ``--pairs`` seeds (default 50): drive the tour for 20–40 s, teleport
  the rover to a random free pose at least 3 m away, then let it turn on the spot; success when
  the published pose is within 0.2 m and 0.1 rad of the truth and the state is ``ok`` within
  15 s of simulated time. ``confidently_wrong`` counts the kidnaps in which the state was
  ``ok`` for at least a second while the pose was more than ``WRONG_M`` (0.5 m) from the truth
  (the dangerous outcome: a rover that drives on a wrong pose it trusts), with the longest such
  time (``confidently_wrong_max_s``).

Run: ``curio bench localization [--pairs N] [--seed N] [--map YAML] [--json PATH]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from curio.commands.bench import BenchOptions
from curio.core.clock import SimClock, process_cpu_time, wall_perf_counter
from curio.core.config import Config, load_config
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import WheelEncoders
from curio.core.topics import LOCALIZATION, POSE, SERVO_CMD, make_bus
from curio.drivers.kinematics import twist_to_servo_command
from curio.drivers.odometry import WheelOdometry
from curio.estimation.ekf import OdomEkf
from curio.estimation.localization import Localizer, LocalizerNode
from curio.robot import RobotModel
from curio.sim.world import World

# A tour of the default building (map metres): lobby → gallery → lab → meeting room → library
# → back to the lobby, through the doors and the corridor.
TOUR: list[tuple[float, float]] = [
    (0.0, 0.0), (2.0, -2.5), (6.0, 1.5), (9.0, 2.0), (12.5, 1.5), (15.5, 0.0), (18.5, -0.1),
    (20.5, 0.0), (20.5, 5.5), (20.5, 8.3), (18.6, 8.3), (18.6, 11.0), (19.5, 12.0),
    (18.6, 11.0), (18.6, 8.3), (1.5, 8.3), (1.5, 11.0), (1.0, 11.8), (1.5, 11.0), (1.5, 8.3),
    (5.0, 8.3), (5.0, 5.0), (0.0, 0.0),
]


@dataclass
class Rig:
    """The simulated rover with the estimation pipeline, stepped by hand."""

    cfg: Config
    world: World
    odometry: WheelOdometry
    ekf: OdomEkf
    node: LocalizerNode
    bus: Any
    t: float = 0.0
    next_wheel: float = 0.0
    next_scan: float = 0.0
    next_ctrl: float = 0.0
    cmd: tuple[float, float] = (0.0, 0.0)
    wp_index: int = 1
    errors: list[tuple[float, float, float]] = field(default_factory=list)
    update_ms: list[float] = field(default_factory=list)
    update_cpu_ms: list[float] = field(default_factory=list)

    @classmethod
    def create(cls, cfg: Config, start: Pose2D) -> Rig:
        cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"start": start.as_tuple()})})
        world = World.from_config(cfg)
        bus = make_bus()
        clock = SimClock()
        odometry = WheelOdometry(RobotModel.from_config(cfg.robot), bus, clock)
        ekf = OdomEkf(cfg.ekf, cfg.robot.imu_pose[2])
        loc = Localizer(world.grid, cfg.localization, Pose2D(*cfg.robot.laser_pose),
                        seed=cfg.sim.seed * 7919 + 4)
        node = LocalizerNode(bus, clock, loc, start)
        return cls(cfg, world, odometry, ekf, node, bus)

    def pose(self) -> Pose2D | None:
        msg = self.bus.latest(POSE)
        return None if msg is None else msg.pose

    def state(self) -> str:
        msg = self.bus.latest(LOCALIZATION)
        return "off" if msg is None else msg.state

    def drive_tour(self) -> tuple[float, float]:
        """Pure pursuit along :data:`TOUR` on the estimated pose (loops for ever)."""
        pose = self.pose()
        if pose is None:
            return (0.0, 0.0)
        tx, ty = TOUR[self.wp_index]
        if math.hypot(tx - pose.x, ty - pose.y) < 0.35:
            self.wp_index = (self.wp_index + 1) % len(TOUR)
            tx, ty = TOUR[self.wp_index]
        err = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.yaw)
        if abs(err) > 0.6:
            return (0.0, math.copysign(0.6, err))
        return (0.3 * max(0.2, math.cos(err)), max(-0.8, min(0.8, 1.5 * err)))

    def step(self, dt: float, controller: Any) -> None:
        """Advance the simulation by one physics step ``dt``."""
        self.t += dt
        self.world.step(dt)
        t = self.t
        self.ekf.add_imu(self.world.imu_sample(t))
        if t >= self.next_wheel:
            self.next_wheel += 1.0 / self.cfg.sim.wheel_feedback_rate_hz
            p = self.world.wheel_positions()
            odom = self.odometry.handle(WheelEncoders(t, (p[0], p[1], p[2], p[3], p[4], p[5])))
            if odom is not None:
                self.ekf.add_wheel_odometry(odom)
        if self.ekf.t_s is not None:
            self.node.on_odom(self.ekf.odometry_at(t))
        if t >= self.next_scan:
            self.next_scan += 1.0 / self.cfg.sim.lidar_rate_hz
            scan = self.world.cast_scan(t)
            before = self.node.localizer.updates
            t0, c0 = wall_perf_counter(), process_cpu_time()
            self.node.on_scan(scan)
            if self.node.localizer.updates > before:
                self.update_ms.append((wall_perf_counter() - t0) * 1000.0)
                self.update_cpu_ms.append((process_cpu_time() - c0) * 1000.0)
        if t >= self.next_ctrl:
            self.next_ctrl += 0.1
            self.cmd = controller()
            servo = twist_to_servo_command(self.cmd[0], self.cmd[1],
                                           RobotModel.from_config(self.cfg.robot), t)
            self.world.apply_servo_command(servo)
            self.bus.publish(SERVO_CMD, servo)
        est = self.pose()
        if est is not None:
            truth = self.world.truth_pose
            self.errors.append((t, est.distance_to(truth), abs(wrap_angle(est.yaw - truth.yaw))))


def _config(opts: BenchOptions, seed: int) -> Config:
    overrides = [f"sim.seed={seed}", "web.enabled=false"]
    if opts.map_yaml:
        overrides.append(f'sim.world="{opts.map_yaml}"')
    return load_config(None, overrides)


def tracking(opts: BenchOptions) -> dict[str, Any]:
    """One long tour; accuracy and cost figures."""
    duration = float(opts.extra.get("duration_s", 900.0))
    cfg = _config(opts, opts.seed)
    rig = Rig.create(cfg, Pose2D(0.0, 0.0, 0.0))
    dt = 1.0 / cfg.sim.physics_rate_hz
    t0 = wall_perf_counter()
    collisions_before = rig.world.collisions
    while rig.t < duration:
        rig.step(dt, rig.drive_tour)
    wall = wall_perf_counter() - t0
    err = np.array([e for e in rig.errors if e[0] > 2.0])
    times = np.array(rig.update_ms)
    return {
        "subject": "curio",
        "test": "tracking",
        "sim_s": round(duration, 1),
        "rmse_m": round(float(np.sqrt(np.mean(err[:, 1] ** 2))), 4),
        "rmse_deg": round(math.degrees(float(np.sqrt(np.mean(err[:, 2] ** 2)))), 3),
        "max_m": round(float(err[:, 1].max()), 4),
        "median_ms": round(float(np.median(times)), 2),
        "p99_ms": round(float(np.percentile(times, 99)), 2),
        "cpu_median_ms": round(float(np.median(rig.update_cpu_ms)), 2),
        "cpu_p99_ms": round(float(np.percentile(rig.update_cpu_ms, 99)), 2),
        "updates": len(rig.update_ms),
        "collisions": rig.world.collisions - collisions_before,
        "rtf": round(duration / wall, 1),
    }


def _random_free_pose(world: World, rng: np.random.Generator, away_from: Pose2D) -> Pose2D:
    grid = world.grid
    from curio.estimation.localization import DistanceField

    field = DistanceField(grid, 2.0)
    ok = grid.free_mask() & (field.dist_m >= 0.6)
    rows, cols = np.nonzero(ok)
    for _ in range(1000):
        i = int(rng.integers(len(rows)))
        x, y = grid.cell_to_world(int(rows[i]), int(cols[i]))
        pose = Pose2D(x, y, float(rng.uniform(-math.pi, math.pi)))
        if pose.distance_to(away_from) >= 3.0 and not world.collides(pose):
            return pose
    raise RuntimeError("no free pose found for the kidnap")


WRONG_M = 0.5  # an ``ok`` pose this far from the truth is confidently wrong (m)


def kidnap_once(opts: BenchOptions, seed: int, limit_s: float = 15.0
                ) -> tuple[float | None, float]:
    """Seconds from the teleport to a correct, confident pose (None if not within
    ``limit_s``), and the longest time (s) the state was ``ok`` on a pose more than
    ``WRONG_M`` from the truth."""
    cfg = _config(opts, seed)
    rng = np.random.default_rng(seed + 1000)
    rig = Rig.create(cfg, Pose2D(0.0, 0.0, 0.0))
    dt = 1.0 / cfg.sim.physics_rate_hz
    drive_s = float(rng.uniform(20.0, 40.0))
    while rig.t < drive_s:
        rig.step(dt, rig.drive_tour)
    target = _random_free_pose(rig.world, rng, rig.world.truth_pose)
    rig.world.teleport(target)
    t_kidnap = rig.t
    good_since: float | None = None
    wrong_since: float | None = None
    wrong_s = 0.0
    while rig.t < t_kidnap + limit_s:
        rig.step(dt, lambda: (0.0, 0.4))
        est = rig.pose()
        truth = rig.world.truth_pose
        if est is not None and rig.state() == "ok":  # how far off a pose it trusts
            off_m, off_rad = est.distance_to(truth), abs(wrap_angle(est.yaw - truth.yaw))
        else:
            off_m = off_rad = math.inf
        ok = off_m < 0.2 and off_rad < 0.1
        if ok and good_since is None:
            good_since = rig.t
        elif not ok:
            good_since = None
        wrong = WRONG_M < off_m < math.inf
        if wrong and wrong_since is None:
            wrong_since = rig.t
        elif not wrong:
            wrong_since = None
        if wrong_since is not None:
            wrong_s = max(wrong_s, rig.t - wrong_since)
        if good_since is not None and rig.t - good_since >= 1.0:
            return good_since - t_kidnap, wrong_s
    return None, wrong_s


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Tracking row and kidnap row for Curio."""
    rows = [tracking(opts)]
    n = opts.pairs or 50
    times: list[float] = []
    wrong: list[float] = []  # seconds confidently wrong, of the kidnaps that were
    t0 = wall_perf_counter()
    for k in range(n):
        got, wrong_s = kidnap_once(opts, opts.seed + k)
        if got is not None:
            times.append(got)
        if wrong_s >= 1.0:
            wrong.append(wrong_s)
    rows.append({
        "subject": "curio",
        "test": "kidnap",
        "seeds": n,
        "success_rate": round(len(times) / n, 3),
        "median_s": round(float(np.median(times)), 2) if times else None,
        "max_s": round(float(np.max(times)), 2) if times else None,
        "confidently_wrong": len(wrong),
        "confidently_wrong_max_s": round(max(wrong), 2) if wrong else None,
        "wall_s": round(wall_perf_counter() - t0, 1),
    })
    return rows
