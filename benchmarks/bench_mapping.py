"""Mapping benchmark: map a loop of the default world and compare with the ground truth.

1. **Record** one loop of the tour of the default building (``sim.world``) in the simulator with
   the ``cfg.sim.noise`` defaults: wheel odometry through the EKF (with the gyro) and the lidar,
   the rover steered along the tour on its true pose (a person driving it by teleop).
2. **Build** the map from the recording with :func:`curio.estimation.mapping.build_map_from_log`
   (scan matching, loop closure), timed on the wall clock: ``rtf`` = recorded seconds / build
   seconds (target ≥ 5).
3. **Compare** with the world's occupancy grid, cell by cell in ``map``:

   * ``occupied_agreement`` — built occupied cells within one cell of a true obstacle
     ("walls within one cell"; target ≥ 0.97);
   * ``free_agreement`` — built free cells that are truly free (target ≥ 0.97);
   * ``wall_recall`` — true wall-surface cells inside the mapped area with a built obstacle
     within one cell;
   * ``coverage`` — share of the true free cells that the map knows;
   * ``scan_p50_ms`` / ``scan_p99_ms`` / ``scan_max_ms`` — wall time of each scan's mapping
     (``ScanMapper.add_scan``, the work ``MappingNode`` does per scan while driving; budget: the
     scan period, 100 ms at 10 Hz) and ``draw_ms`` — drawing the whole map once (done off the
     per-scan path online).

4. **Real data**: the MIT CSAIL CARMEN log (``../shared/datasets/mit-csail.clf``, 424 s, 1988
   SICK scans) is mapped as ``curio map build`` does and its trajectory scored with the
   Freiburg SLAM benchmark's ground-truth relations (``mit-csail.relations``; Kümmerle et
   al. 2009; :mod:`curio.estimation.relations`): ``trans_mean_m`` / ``trans_std_m`` /
   ``trans_max_m``, ``rot_mean_deg`` / ``rot_std_deg`` / ``rot_max_deg``, ``relations_matched``
   of ``relations``, the build's wall time and ``rtf``. Targets: ≤ 0.030 m and ≤ 0.5° mean, no
   relation worse than 0.5 m, ≥ 10× real time. Without the data the row says why it was
   skipped (``skipped``) instead of failing.

Run: ``curio bench mapping [--seed N] [--json PATH] [--set seeds=1,2,3] [--set loops=N]
[--set sim=0] [--set log=LOG.clf --set relations=LOG.relations]`` — ``seeds`` maps several
simulated seeds, ``sim=0`` only the real log, ``log``/``relations`` score another Freiburg
benchmark log (Intel, ACES, FR079 ...) instead of CSAIL.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from benchmarks.bench_localization import TOUR
from curio.commands.bench import BenchOptions
from curio.core.clock import SimClock, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import WheelEncoders
from curio.core.topics import SERVO_CMD, make_bus
from curio.drivers.kinematics import twist_to_servo_command
from curio.drivers.odometry import WheelOdometry
from curio.estimation.carmen import LogScan, read_carmen
from curio.estimation.ekf import OdomEkf
from curio.estimation.mapping import MapperParams, build_map_from_log
from curio.estimation.maps import OccupancyGrid
from curio.estimation.relations import RelationError, read_relations, score_trajectory
from curio.robot import RobotModel
from curio.sim.world import World

MIT_LOG = REPO_ROOT.parent / "shared" / "datasets" / "mit-csail.clf"


def record_tour(opts: BenchOptions, loops: int = 1,
                truth: list[Pose2D] | None = None) -> tuple[list[LogScan], World, float]:
    """Drive ``loops`` tours; return the scans with EKF odometry, the world and the duration.

    ``truth``, if given, receives the true pose at each scan.
    """
    overrides = [f"sim.seed={opts.seed}", "web.enabled=false"]
    if opts.map_yaml:
        overrides.append(f'sim.world="{opts.map_yaml}"')
    cfg = load_config(None, overrides)
    world = World.from_config(cfg)
    bus = make_bus()
    odometry = WheelOdometry(RobotModel.from_config(cfg.robot), bus, SimClock())
    ekf = OdomEkf(cfg.ekf, cfg.robot.imu_pose[2])
    laser = Pose2D(*cfg.robot.laser_pose)
    dt = 1.0 / cfg.sim.physics_rate_hz
    t = next_wheel = next_scan = next_ctrl = 0.0
    wp = 1
    done_loops = 0
    scans: list[LogScan] = []
    while done_loops < loops and t < 3600.0:
        t += dt
        world.step(dt)
        ekf.add_imu(world.imu_sample(t))
        if t >= next_wheel:
            next_wheel += 1.0 / cfg.sim.wheel_feedback_rate_hz
            p = world.wheel_positions()
            odom = odometry.handle(WheelEncoders(t, (p[0], p[1], p[2], p[3], p[4], p[5])))
            if odom is not None:
                ekf.add_wheel_odometry(odom)
        if t >= next_scan and ekf.t_s is not None:
            next_scan += 1.0 / cfg.sim.lidar_rate_hz
            scan = world.cast_scan(t)
            r = np.asarray(scan.ranges_m, dtype=np.float64)
            r = np.where(scan.valid_mask(), r, np.inf)
            scans.append(LogScan(t, ekf.odometry_at(t).pose, laser, scan.angle_min_rad,
                                 scan.angle_increment_rad, r, scan.range_max_m))
            if truth is not None:
                truth.append(world.truth_pose)
        if t >= next_ctrl:
            next_ctrl += 0.1
            pose = world.truth_pose
            tx, ty = TOUR[wp]
            if math.hypot(tx - pose.x, ty - pose.y) < 0.35:
                wp = (wp + 1) % len(TOUR)
                if wp == 1:
                    done_loops += 1
                tx, ty = TOUR[wp]
            err = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.yaw)
            if abs(err) > 0.6:
                v, w = 0.0, math.copysign(0.6, err)
            else:
                v, w = 0.3 * max(0.2, math.cos(err)), max(-0.8, min(0.8, 1.5 * err))
            servo = twist_to_servo_command(v, w, RobotModel.from_config(cfg.robot), t)
            world.apply_servo_command(servo)
            bus.publish(SERVO_CMD, servo)
    return scans, world, t


def compare(built: OccupancyGrid, truth: OccupancyGrid) -> dict[str, float]:
    """Cell-by-cell agreement of a built map with the true one (both in ``map``)."""
    true_occ = truth.occupied_mask()
    near_occ = ndimage.binary_dilation(true_occ, structure=np.ones((3, 3), dtype=bool))
    true_free = truth.free_mask()

    def lookup(mask: np.ndarray[Any, Any], rows: np.ndarray[Any, Any],
               cols: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        xy = np.array([built.cell_to_world(int(r), int(c)) for r, c in zip(rows, cols,
                                                                             strict=True)])
        cells = truth.world_to_cells(xy) if len(xy) else np.zeros((0, 2), dtype=np.int64)
        inside = ((cells[:, 0] >= 0) & (cells[:, 0] < truth.height) & (cells[:, 1] >= 0)
                  & (cells[:, 1] < truth.width))
        out = np.zeros(len(cells), dtype=bool)
        out[inside] = mask[cells[inside, 0], cells[inside, 1]]
        return out

    b_occ_r, b_occ_c = np.nonzero(built.occupied_mask())
    b_free_r, b_free_c = np.nonzero(built.free_mask())
    occ_ok = lookup(near_occ, b_occ_r, b_occ_c)
    free_ok = lookup(~true_occ, b_free_r, b_free_c)
    # Wall surfaces of the truth inside the mapped area.
    surface = true_occ & ndimage.binary_dilation(true_free)
    built_occ_near = ndimage.binary_dilation(built.occupied_mask(),
                                             structure=np.ones((3, 3), dtype=bool))
    built_known_near = ndimage.binary_dilation(built.free_mask(), iterations=2)
    s_r, s_c = np.nonzero(surface)
    xy = np.array([truth.cell_to_world(int(r), int(c)) for r, c in zip(s_r, s_c, strict=True)])
    cells = built.world_to_cells(xy)
    inside = ((cells[:, 0] >= 0) & (cells[:, 0] < built.height) & (cells[:, 1] >= 0)
              & (cells[:, 1] < built.width))
    known = np.zeros(len(cells), dtype=bool)
    hit = np.zeros(len(cells), dtype=bool)
    known[inside] = built_known_near[cells[inside, 0], cells[inside, 1]]
    hit[inside] = built_occ_near[cells[inside, 0], cells[inside, 1]]
    f_r, f_c = np.nonzero(true_free)
    fxy = np.array([truth.cell_to_world(int(r), int(c)) for r, c in zip(f_r, f_c, strict=True)])
    fcells = built.world_to_cells(fxy)
    fin = ((fcells[:, 0] >= 0) & (fcells[:, 0] < built.height) & (fcells[:, 1] >= 0)
           & (fcells[:, 1] < built.width))
    fknown = np.zeros(len(fcells), dtype=bool)
    fknown[fin] = built.data[fcells[fin, 0], fcells[fin, 1]] >= 0
    return {
        "occupied_agreement": float(occ_ok.mean()) if len(occ_ok) else 0.0,
        "free_agreement": float(free_ok.mean()) if len(free_ok) else 0.0,
        "wall_recall": float(hit[known].mean()) if known.any() else 0.0,
        "coverage": float(fknown.mean()) if len(fknown) else 0.0,
    }


def align(est: list[Pose2D], truth: list[Pose2D]) -> Pose2D:
    """The rigid transform T minimising Σ|T·est_i − truth_i|² (2-D Kabsch on positions)."""
    a = np.array([(p.x, p.y) for p in est])
    b = np.array([(p.x, p.y) for p in truth])
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    yaw = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(yaw), math.sin(yaw)
    t = cb - np.array([[c, -s], [s, c]]) @ ca
    return Pose2D(float(t[0]), float(t[1]), yaw)


def sim_row(opts: BenchOptions, loops: int) -> dict[str, Any]:
    """Map ``loops`` tours of the default world (seed ``opts.seed``) and compare with the truth."""
    truth: list[Pose2D] = []
    scans, world, duration = record_tour(opts, loops, truth)
    start = Pose2D(*(world.cfg.sim.start or world.cfg.robot.home))
    marks: list[float] = []
    t0 = wall_perf_counter()
    mapper = build_map_from_log(scans, MapperParams(max_range_m=world.cfg.sim.lidar_range_max_m),
                                lambda _n: marks.append(wall_perf_counter()), initial=start)
    t1 = wall_perf_counter()
    built = mapper.occupancy()
    t2 = wall_perf_counter()
    wall = t2 - t0
    # Per scan: the work MappingNode does for each scan while driving (the same add_scan).
    per_scan = np.diff(np.array([t0, *marks])) * 1000.0
    # The map's frame is the first pose's estimate: also compare up to a rigid transform,
    # fitted on the trajectory (``occupied_agreement``); unaligned is the figure that counts.
    est = [p for _, p in mapper.trajectory]
    fit = align(est, truth)
    err = np.array([(fit @ p).distance_to(t) for p, t in zip(est, truth, strict=True)])
    raw = compare(built, world.grid)
    built.origin = fit @ built.origin
    figures = compare(built, world.grid)
    return {
        "subject": "curio",
        "test": f"default-world loop, seed {opts.seed}",
        "sim_s": round(duration, 1),
        "build_s": round(wall, 2),
        "rtf": round(duration / wall, 1),
        **{k: round(v, 4) for k, v in figures.items()},
        "occupied_agreement_unaligned": round(raw["occupied_agreement"], 4),
        "frame_offset_m": round(math.hypot(fit.x, fit.y), 4),
        "frame_offset_deg": round(math.degrees(fit.yaw), 3),
        "trajectory_rmse_m": round(float(np.sqrt(np.mean(err**2))), 4),
        "trajectory_max_m": round(float(err.max()), 4),
        "loop_closures": len(mapper.loop_edges),
        "keyframes": len(mapper.keyframes),
        "scan_p50_ms": round(float(np.median(per_scan)), 2),
        "scan_p99_ms": round(float(np.percentile(per_scan, 99)), 1),
        "scan_max_ms": round(float(per_scan.max()), 1),
        "draw_ms": round((t2 - t1) * 1000.0, 1),
    }


def log_row(log: Path, relations: Path) -> dict[str, Any]:
    """Map a CARMEN log like ``curio map build`` and score it with its relations file."""
    row: dict[str, Any] = {"subject": "curio", "test": log.name}
    if not log.is_file() or not relations.is_file():
        missing = log if not log.is_file() else relations
        row["skipped"] = f"{missing} not found (the shared datasets are not checked out)"
        return row
    try:
        rels = read_relations(relations)
    except RelationError as exc:
        row["skipped"] = str(exc)
        return row
    t0 = wall_perf_counter()
    mapper = build_map_from_log(read_carmen(log), MapperParams(max_range_m=25.0))
    mapper.occupancy()
    wall = wall_perf_counter() - t0
    traj = np.array([(t, p.x, p.y, p.yaw) for t, p in mapper.trajectory])
    sc = score_trajectory(traj, rels)
    span = float(traj[-1, 0] - traj[0, 0])
    row.update({
        "trans_mean_m": round(sc.trans_mean_m, 4),
        "trans_std_m": round(sc.trans_std_m, 4),
        "trans_max_m": round(sc.trans_max_m, 3),
        "rot_mean_deg": round(sc.rot_mean_deg, 3),
        "rot_std_deg": round(sc.rot_std_deg, 3),
        "rot_max_deg": round(sc.rot_max_deg, 2),
        "relations_matched": sc.matched,
        "relations": sc.relations,
        "log_s": round(span, 1),
        "build_s": round(wall, 2),
        "rtf": round(span / wall, 1),
        "loop_closures": len(mapper.loop_edges),
        "keyframes": len(mapper.keyframes),
    })
    return row


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Simulated default-world rows (one per seed), then the real log's row."""
    loops = int(opts.extra.get("loops", 1))
    seeds = [int(s) for s in str(opts.extra.get("seeds", opts.seed)).split(",") if s.strip()]
    rows: list[dict[str, Any]] = []
    if str(opts.extra.get("sim", "1")) not in ("0", "false", "no"):
        for seed in seeds:
            rows.append(sim_row(BenchOptions(opts.map_yaml, opts.pairs, seed, opts.extra), loops))
    log = Path(opts.extra.get("log", MIT_LOG))
    relations = Path(opts.extra.get("relations", log.with_suffix(".relations")))
    rows.append(log_row(log, relations))
    return rows
