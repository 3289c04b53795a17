"""Simulator real-time factor: simulated seconds per wall second (``curio bench sim``).

What runs: the default world (``maps/curio_building.yaml`` or ``--map``), the simulator's
physics loop (``physics_rate_hz`` 50, with ``/ground_truth``), the lidar at 10 Hz with 360
beams, the IMU at 100 Hz, wheel feedback at 30 Hz, the battery, and the simulated base
receiving ``/cmd_vel`` at 10 Hz that drives the rover round a 1.5 m-radius circle in the lobby —
all on one :class:`~curio.core.clock.SimClock` in one thread (one core).

Rows:

* ``curio`` — the default ray caster (``GridRaycaster``, compiled exact traversal);
* ``curio-numpy-backend`` — the same simulator with the all-beams-at-once numpy caster;
* ``naive-python-raycaster`` — the same simulator with a per-beam Python loop ray caster (half-
  cell steps), the usual first implementation; run for a shorter simulated time.

Figures: ``rtf`` (simulated s / wall s), ``rtf_cpu`` (simulated s / CPU s of this process:
the one-core figure, robust to other load on a shared machine), ``scan_ms_median`` /
``scan_ms_p99`` (one 360-beam revolution, wall ms), ``physics_us_median`` (one physics step,
wall µs), ``sim_s``, ``wall_s``, and for the peers ``rtf_ratio`` (curio's ``rtf_cpu`` / the
peer's).
"""

from __future__ import annotations

import asyncio
import math
from typing import Any

import numpy as np

from curio.commands.bench import BenchOptions
from curio.core.bus import Bus
from curio.core.clock import SimClock, process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, make_bus
from curio.sim.base import SimBase
from curio.sim.raycast import naive_cast
from curio.sim.wiring import Simulator
from curio.sim.world import World


def _config(opts: BenchOptions) -> Config:
    sets = ["web.enabled=false", "sim.lidar_rate_hz=10.0", "sim.lidar_beams=360",
            f"sim.seed={opts.seed}"]
    cfg = load_config(REPO_ROOT / "config.toml", sets)
    if opts.map_yaml:
        cfg.sim.world = opts.map_yaml
    return cfg


def _run_once(cfg: Config, sim_s: float, naive: bool, backend: str = "compiled") -> dict[str, Any]:
    world = World.from_config(cfg)
    world.raycaster.backend = backend
    scan_times: list[float] = []
    step_times: list[float] = []
    cast = world.raycaster.cast
    if naive:
        grid = world.grid

        def naive_ranges(ox: float, oy: float, angles: Any, max_range: float) -> Any:
            return naive_cast(grid, ox, oy, angles, max_range)

        cast = naive_ranges

    def timed_cast(ox: float, oy: float, angles: Any, max_range: float) -> Any:
        t0 = wall_perf_counter()
        out = cast(ox, oy, angles, max_range)
        scan_times.append(wall_perf_counter() - t0)
        return out

    world.raycaster.cast = timed_cast  # type: ignore[method-assign]
    step = world.step

    def timed_step(dt: float) -> None:
        t0 = wall_perf_counter()
        step(dt)
        step_times.append(wall_perf_counter() - t0)

    world.step = timed_step  # type: ignore[method-assign]

    async def main() -> tuple[float, float]:
        clock = SimClock()
        bus: Bus = make_bus()
        sim = Simulator(cfg, bus, clock, world, publish_sensors=True)
        base = SimBase(cfg, bus, clock, world)
        bus.bind_loop(asyncio.get_running_loop())

        async def driver() -> None:
            async for t in clock.every(0.1):  # type: ignore[attr-defined]
                bus.publish(CMD_VEL, Twist(t, 0.3, 0.2, source="bench"))

        coros = [sim.run_physics(), sim.run_scan(), sim.run_imu(), sim.run_wheels(),
                 sim.run_battery(), base.run(), base.run_watchdog(), driver()]
        tasks = [asyncio.create_task(c) for c in coros]
        t0, c0 = wall_perf_counter(), process_cpu_time()
        await clock.run(until_s=sim_s)
        wall, cpu = wall_perf_counter() - t0, process_cpu_time() - c0
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        return wall, cpu

    wall, cpu = asyncio.run(main())
    scans = np.array(scan_times) * 1e3
    steps = np.array(step_times) * 1e6
    return {
        "rtf": round(sim_s / wall, 1),
        "rtf_cpu": round(sim_s / cpu, 1),
        "scan_ms_median": round(float(np.median(scans)), 3),
        "scan_ms_p99": round(float(np.percentile(scans, 99)), 3),
        "physics_us_median": round(float(np.median(steps)), 1),
        "scans": len(scan_times),
        "sim_s": sim_s,
        "wall_s": round(wall, 3),
        "collisions": world.collisions,
        "distance_from_start_m": round(math.hypot(world.truth_pose.x, world.truth_pose.y), 3),
    }


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the benchmark: the vectorised caster, then the per-beam Python loop peer."""
    cfg = _config(opts)
    sim_s = float(opts.extra.get("sim_s", 120.0))
    _run_once(cfg, 2.0, naive=False)  # warm-up (imports, caches)
    ours = {"subject": "curio", "lidar_hz": 10, "beams": 360, **_run_once(cfg, sim_s, False)}
    vect = {"subject": "curio-numpy-backend", "lidar_hz": 10, "beams": 360,
            **_run_once(cfg, sim_s / 2, False, backend="numpy")}
    peer_s = float(opts.extra.get("peer_sim_s", 5.0))
    peer = {"subject": "naive-python-raycaster", "lidar_hz": 10, "beams": 360,
            **_run_once(cfg, peer_s, True)}
    for row in (vect, peer):
        row["rtf_ratio"] = round(ours["rtf_cpu"] / row["rtf_cpu"], 1) if row["rtf_cpu"] else None
    return [ours, vect, peer]
