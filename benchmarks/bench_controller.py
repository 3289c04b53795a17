"""Local controller benchmark: time per control cycle, and the navigation stack's CPU share.

``curio bench controller [--map YAML] [--pairs N] [--seed N]``

Rows:

* ``curio`` — :meth:`~curio.nav.controller.LocalController.compute` timed (wall clock, one
  call per cycle) while the controller drives a unicycle model along N global plans (default
  20) between random free poses of the map (default: the shipped building), on the costmap
  of the shipped config. Figures: ``median_ms``, ``mean_ms``, ``p99_ms``, ``max_ms``,
  ``cycles``, ``goals_reached``; ``cpu_median_ms`` / ``cpu_p99_ms`` are the same in thread CPU
  time, which other processes on a busy machine disturb less. Target: p99 ≤ 10 ms.
* ``curio (avoiding)`` — the same with a box dropped on every plan (marked in the costmap,
  as the obstacle layer would), so the collision check fails and the arc sampler runs: the
  controller's worst case.
* ``curio nav stack`` — the whole application on the simulator, one ``goto`` across the
  building; every cycle of the navigation parts (costmap update, navigator = planner +
  controller, obstacle extraction + blocked detector, safety stage) is timed in thread CPU
  time. ``cpu_fraction`` = their CPU seconds / simulated seconds: the share of one core the
  stack needs at real time (target < 0.15). ``per_part`` breaks it down.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from curio.commands.bench import BenchOptions, prepare_kernels
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.geometry import Pose2D, wrap_angle
from curio.estimation.maps import OccupancyGrid, load_map
from curio.nav.api import NavError
from curio.nav.controller import ControlStatus, LocalController
from curio.nav.costmap import Costmap
from curio.nav.planner import GlobalPlanner
from curio.robot import RobotModel


def _cfg(opts: BenchOptions) -> Config:
    over = ["web.enabled=false", 'data_dir="/tmp/curio-bench-controller"']
    if opts.map_yaml:
        over.append(f'sim.world="{opts.map_yaml}"')
    return load_config(REPO_ROOT / "config.toml", over)


def _step(pose: Pose2D, v: float, w: float, dt: float) -> Pose2D:
    th = pose.yaw + 0.5 * w * dt
    return Pose2D(pose.x + v * dt * math.cos(th), pose.y + v * dt * math.sin(th),
                  wrap_angle(pose.yaw + w * dt))


def _pairs(cfg: Config, n: int, seed: int) -> list[tuple[Pose2D, Pose2D]]:
    from curio.scenarios.goto import pick_free_pose

    rng = np.random.default_rng([seed, 0xC7])
    out = []
    for _ in range(n):
        a = pick_free_pose(cfg, rng)
        b = pick_free_pose(cfg, rng, a, 3.0)
        out.append((a, b))
    return out


def _drive(cfg: Config, grid: OccupancyGrid, pairs: list[tuple[Pose2D, Pose2D]],
           drop_box: bool) -> dict[str, Any]:
    planner = GlobalPlanner(cfg.nav.planner)
    times: list[float] = []
    cpu_times: list[float] = []
    reached = 0
    for start, goal in pairs:
        cm = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
        try:
            plan = planner.plan(start, goal, cm.costs(), cm.resolution_m, cm.origin)
        except NavError:
            continue
        if drop_box and len(plan) > 40:
            mid = plan[len(plan) // 2]
            data = grid.data.copy()
            r, c = cm.world_to_cell(mid.x, mid.y)
            data[max(0, r - 3):r + 3, max(0, c - 3):c + 3] = 100
            cm = Costmap(OccupancyGrid(data, grid.resolution_m, grid.origin),
                         RobotModel.from_config(cfg.robot),
                         cfg.nav.costmap)
        ctrl = LocalController(cfg.nav.controller, RobotModel.from_config(cfg.robot), cm)
        ctrl.set_plan(plan, Pose2D(goal.x, goal.y, math.nan), check_yaw=False)
        pose = start
        dt = ctrl.dt_s
        for k in range(int(240.0 / dt)):
            c0 = time.thread_time()
            t0 = time.perf_counter()
            out = ctrl.compute(pose, k * dt)
            times.append(time.perf_counter() - t0)
            cpu_times.append(time.thread_time() - c0)
            if out.status is ControlStatus.GOAL_REACHED:
                reached += 1
                break
            if out.status in (ControlStatus.BLOCKED, ControlStatus.NO_PROGRESS):
                break
            pose = _step(pose, out.linear_mps, out.angular_radps, dt)
    ms = np.array(times) * 1000.0
    cpu = np.array(cpu_times) * 1000.0
    return {"median_ms": float(np.median(ms)), "mean_ms": float(ms.mean()),
            "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max()),
            "cpu_median_ms": float(np.median(cpu)), "cpu_p99_ms": float(np.percentile(cpu, 99)),
            "cycles": len(ms), "goals_reached": reached, "goals": len(pairs)}


async def _stack_cpu(cfg: Config, seed: int) -> dict[str, Any]:
    """Run one goto with the navigation parts' cycles timed in thread CPU time."""
    from curio.nav.costmap import CostmapNode
    from curio.nav.navigator import NavigatorNode
    from curio.nav.obstacles import ObstacleNode
    from curio.safety.stage import SafetyStage
    from curio.scenarios import get_scenario
    from curio.scenarios.base import ScenarioArgs, run_scenario

    cpu: dict[str, float] = {}
    originals: list[tuple[type, str, Callable[..., Any]]] = []

    def wrap(cls: type, name: str, label: str) -> None:
        orig = getattr(cls, name)
        originals.append((cls, name, orig))

        def timed(self: Any, *a: Any, **k: Any) -> Any:
            t0 = time.thread_time()
            try:
                return orig(self, *a, **k)
            finally:
                cpu[label] = cpu.get(label, 0.0) + time.thread_time() - t0

        setattr(cls, name, timed)

    wrap(CostmapNode, "step", "costmap")
    wrap(NavigatorNode, "step", "navigator")
    wrap(ObstacleNode, "step", "obstacles_blocked")
    wrap(SafetyStage, "step", "safety")
    try:
        args = ScenarioArgs(start=(0.0, 0.0, 0.0), goal=(18.5, 10.5, None), seed=seed,
                            duration_s=300.0)
        report = await run_scenario(get_scenario("goto"), cfg, args)
    finally:
        for cls, name, orig in originals:
            setattr(cls, name, orig)
    sim_s = float(report["sim_time_s"])
    total = sum(cpu.values())
    return {"cpu_fraction": total / sim_s, "sim_time_s": sim_s,
            "success": report["success"],
            "per_part": {k: round(v / sim_s, 4) for k, v in sorted(cpu.items())}}


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the benchmark and return its rows."""
    cfg = _cfg(opts)
    grid = load_map(cfg.resolve(cfg.sim.world))
    n = opts.pairs or 20
    pairs = _pairs(cfg, n, opts.seed)
    prepare_kernels()
    GlobalPlanner(cfg.nav.planner).warm_up()
    rows: list[dict[str, Any]] = []
    rows.append({"subject": "curio", "map": cfg.sim.world, **_drive(cfg, grid, pairs, False),
                 "target_p99_ms": 10.0})
    rows.append({"subject": "curio (avoiding)", "map": cfg.sim.world,
                 **_drive(cfg, grid, pairs, True), "target_p99_ms": 10.0})
    if not opts.map_yaml:
        stack = asyncio.run(_stack_cpu(cfg, opts.seed))
        rows.append({"subject": "curio nav stack", "map": cfg.sim.world, **stack,
                     "target_cpu_fraction": 0.15})
    return rows
