"""Whole-application speed: a tour through the full stack on simulated time, on one core.

The subject is the complete app — simulator, odometry, EKF, localisation, costmap, planner,
controller, safety stage, behaviour tree and the dashboard hub with no clients — running a
scenario as fast as one core allows. The real-time factor (simulated seconds per wall second)
is the Pi's headroom: the target is ≥ 20× here. ``rtf_cpu`` (simulated seconds per CPU second of
the process) is the same figure with other load on the machine factored out. The subject runs
the ``guided-tour`` scenario (the tour guide visits the five stops of the shipped config,
then goes home); the same run without the dashboard hub shows what the hub costs.

Options (``--set``): ``scenario=guided-tour`` (any ``curio sim`` scenario), ``duration=1800``.
"""

from __future__ import annotations

import asyncio
import os
import tempfile
from typing import Any

from curio.commands.bench import BenchOptions
from curio.core.clock import process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


def _one(label: str, scenario_name: str, overrides: list[str], web: bool, seed: int,
         duration_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(REPO_ROOT / "config.toml",
                          [f'data_dir="{tmp}"', "web.port=0", "bt.speak=false", *overrides])
        args = ScenarioArgs(seed=seed, speed=None, duration_s=duration_s, web=web)
        cpu0, wall0 = process_cpu_time(), wall_perf_counter()
        report = asyncio.run(run_scenario(get_scenario(scenario_name), cfg, args))
        cpu, wall = process_cpu_time() - cpu0, wall_perf_counter() - wall0
    return {
        "subject": label,
        "scenario": scenario_name,
        "success": report["success"],
        "sim_time_s": report["sim_time_s"],
        "wall_time_s": round(wall, 3),
        "rtf": round(report["sim_time_s"] / wall, 2) if wall > 0 else None,
        "rtf_cpu": round(report["sim_time_s"] / cpu, 2) if cpu > 0 else None,
        "cpu_fraction": round(cpu / wall, 3) if wall > 0 else None,
        "goals": f"{report['goals_reached']}/{report['goals_total']}",
        "collisions": report["collisions"],
    }


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the scenario with and without the dashboard hub; one row each."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    scenario_name = str(opts.extra.get("scenario", "guided-tour"))
    duration_s = float(opts.extra.get("duration", 1800))
    # Untimed warm-up: imports and compiled-kernel loading are paid once per process, not by
    # whichever subject happens to run first.
    _one("warm-up", scenario_name, [], True, opts.seed, 5.0)
    rows = [
        _one("curio (full stack, web hub)", scenario_name, [], True, opts.seed, duration_s),
        _one("curio without web hub", scenario_name, [], False, opts.seed, duration_s),
    ]
    full = rows[0]["rtf"] or 0.0
    for row in rows:
        row["rtf_vs_full"] = round((row["rtf"] or 0.0) / full, 2) if full else None
    return rows
