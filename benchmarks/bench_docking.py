"""Docking benchmark: hundreds of final approaches from random errors at the staging pose.

``curio bench docking [--pairs N] [--seed N] [--set workers=2]``

The whole application runs in the simulator (``drivers.mode = "sim"``, the default building,
``dock.enabled``: the dock's shape and charging contact at home, the dock drawn into the map):
EKF, particle-filter localisation, the docker's lidar perception of the dock's shape, the
approach law, the safety stage (in its docking mode) and the simulated base with its
steering servos, wheel scale error and lidar noise. For each attempt the rover is put at the
staging pose (``dock.staging_distance_m`` = 0.7 m straight out of the dock) plus a random error
— a position error of up to 0.3 m in a random direction and a heading error of up to ±15°,
uniform, from the seed —, the localiser is told where it is (as after driving to the staging
pose; its estimate then converges as usual), and the docker starts its final approach there
(``Docker.dock(from_here=True)``: the staging goal itself is the navigator's, measured by
``curio bench nav``). The attempt ends docked (the charging contact touches: the charger's
voltage on ``/battery``) or failed (after ``dock.max_attempts`` approaches); the rover then
undocks.

``--pairs N`` is the number of attempts (default 200), split over ``workers`` processes (one
App each, default 2). Row ``curio``: ``attempts``, ``success_rate``, ``retried`` (attempts that
needed more than one approach), ``median_error_m``, ``p95_error_m``, ``max_error_m`` (the
ground-truth distance of ``base_link`` from the docked pose), the same in degrees, ``collisions``
(simulator contacts, the dock included), ``median_time_s`` (simulated, approach to contact),
``sim_time_s``, ``wall_time_s``. Targets (issue 11): success ≥ 99 %, error ≤ 2 cm and ≤ 2°,
no collision with the dock.
"""

from __future__ import annotations

import asyncio
import math
import multiprocessing
import tempfile
import time
from typing import Any

import numpy as np

from curio.commands.bench import BenchOptions
from curio.core.config import load_config
from curio.core.geometry import Pose2D
from curio.core.messages import PoseWithCovariance
from curio.core.topics import EVENTS, INITIAL_POSE

MAX_XY_M = 0.3
MAX_YAW_DEG = 15.0
ATTEMPT_LIMIT_S = 150.0


def staging_errors(n: int, seed: int) -> list[tuple[float, float, float]]:
    """``n`` errors (dx, dy m in the dock frame, dyaw rad): position uniform in a 0.3 m disc,
    heading uniform in ±15°."""
    rng = np.random.default_rng([seed, 0xD0C])
    out = []
    for _ in range(n):
        r = MAX_XY_M * math.sqrt(float(rng.uniform()))
        a = float(rng.uniform(-math.pi, math.pi))
        out.append((r * math.cos(a), r * math.sin(a),
                    math.radians(float(rng.uniform(-MAX_YAW_DEG, MAX_YAW_DEG)))))
    return out


async def _attempts(errors: list[tuple[float, float, float]], seed: int) -> list[dict[str, Any]]:
    """Run the attempts in one App."""
    from curio.app import App
    from curio.core.clock import SimClock

    data = tempfile.mkdtemp(prefix="curio-bench-docking-")
    cfg = load_config(None, [f'data_dir="{data}"', "web.enabled=false", "dock.enabled=true",
                             f"sim.seed={seed}", "bt.speak=false"])
    clock = SimClock()
    app = App(cfg, clock, web=False)
    assert app.docker is not None and app.world is not None and app.world.dock is not None
    events = app.bus.subscribe(EVENTS)
    await app.start()
    await clock.run(until_s=clock.now() + 2.0)
    rows = []
    for dx, dy, dyaw in errors:
        rows.append(await _one(app, clock, events, Pose2D(dx, dy, dyaw)))
    await app.stop()
    return rows


async def _one(app: Any, clock: Any, events: Any, error: Pose2D) -> dict[str, Any]:
    docker, world = app.docker, app.world
    start = app.home.staging() @ error
    world.teleport(start)
    app.bus.publish(INITIAL_POSE, PoseWithCovariance(clock.now(), start, covariance=(
        0.0025, 0.0, 0.0, 0.0, 0.0025, 0.0, 0.0, 0.0, 0.0009)))
    await clock.run(until_s=clock.now() + 1.5)
    docker.state, docker.detail = "idle", "bench"
    events.drain()
    t0 = clock.now()
    docker.dock("bench", from_here=True)
    while docker.state not in ("docked", "failed") and clock.now() - t0 < ATTEMPT_LIMIT_S:
        await clock.run(until_s=clock.now() + 0.5)
    took = clock.now() - t0
    dx, dy, dyaw = world.dock.error(world.truth_pose)
    evs = events.drain()
    collisions = sum(1 for e in evs if e.kind == "collision")
    approaches = sum(1 for e in evs if e.kind == "dock.attempt")
    ok = docker.state == "docked" and world.docked
    if docker.state == "docked":
        docker.undock()
        while docker.state == "undocking":
            await clock.run(until_s=clock.now() + 0.5)
    return {"ok": ok, "error_m": math.hypot(dx, dy), "error_deg": abs(math.degrees(dyaw)),
            "collisions": collisions, "approaches": approaches, "time_s": took,
            "start_error_m": math.hypot(error.x, error.y),
            "start_error_deg": math.degrees(error.yaw)}


def _chunk(args: tuple[list[tuple[float, float, float]], int]) -> list[dict[str, Any]]:
    errors, seed = args
    return asyncio.run(_attempts(errors, seed))


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """The benchmark (see the module docstring)."""
    n = opts.pairs or 200
    workers = max(1, int(opts.extra.get("workers", 2)))
    errors = staging_errors(n, opts.seed)
    chunks = [(errors[i::workers], opts.seed * 1000 + i) for i in range(workers)]
    t0 = time.perf_counter()
    if workers == 1:
        results = [_chunk(chunks[0])]
    else:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            results = pool.map(_chunk, chunks)
    wall = time.perf_counter() - t0
    rows = [r for part in results for r in part]
    ok = [r for r in rows if r["ok"]]
    err_m = np.array([r["error_m"] for r in ok]) if ok else np.array([math.nan])
    err_deg = np.array([r["error_deg"] for r in ok]) if ok else np.array([math.nan])
    return [{
        "subject": "curio",
        "attempts": len(rows),
        "success_rate": round(len(ok) / max(1, len(rows)), 4),
        "retried": sum(1 for r in rows if r["approaches"] > 1),
        "median_error_m": round(float(np.median(err_m)), 4),
        "p95_error_m": round(float(np.percentile(err_m, 95)), 4),
        "max_error_m": round(float(err_m.max()), 4),
        "median_error_deg": round(float(np.median(err_deg)), 3),
        "p95_error_deg": round(float(np.percentile(err_deg, 95)), 3),
        "max_error_deg": round(float(err_deg.max()), 3),
        "collisions": sum(r["collisions"] for r in rows),
        "median_time_s": round(float(np.median([r["time_s"] for r in rows])), 1),
        "sim_time_s": round(sum(r["time_s"] for r in rows), 1),
        "wall_time_s": round(wall, 1),
        "targets_met": bool(len(ok) >= 0.99 * len(rows) and float(err_m.max()) <= 0.02
                            and float(err_deg.max()) <= 2.0
                            and sum(r["collisions"] for r in rows) == 0),
    }]
