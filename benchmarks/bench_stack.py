"""Whole-application speed: a tour through the full stack on simulated time, on one core.

The subject is the complete app — simulator, odometry, EKF, localisation, costmap, planner,
controller, safety stage, behaviour tree and the dashboard hub with no clients — running a
scenario as fast as one core allows (the ``guided-tour`` scenario: the tour guide visits the
five stops of the shipped config, then goes home); the same run without the dashboard hub
shows what the hub costs.

Figures per row (medians over ``repeats`` runs; the machine is shared, so CPU time is the
figure to trust):

* ``rtf`` — simulated seconds per wall second of the whole process (simulator included);
  ``rtf_cpu`` — per CPU second (other load on the machine factored out). Target ≥ 40×.
* ``app_cpu_per_sim_s`` — CPU seconds **of the application alone** per simulated second, i.e.
  the share of one core it needs at real time (``app_pct_core`` in percent; target ≤ 1.5 %).
  Measured from the app's start to the scenario's end with :class:`curio.core.cpu_meter.CpuMeter`:
  the process's CPU minus the simulator's tasks (``sim.*``, the device emulators:
  ``sim_cpu_s``) and the scenario harness (its script, collector and the simulated clock's
  stepping: ``harness_cpu_s``). The event loop's own machinery stays in the application's
  figure, as it does on the rover (the meter's ~1 µs per metered step lands there too: the
  conservative side).
* ``naive_scans_per_cpu_s`` — the calibration (``benchmarks/calibration.py``): the naive Python
  ray caster's throughput, measured in the same run, before, between and after the subjects
  (median). ``app_naive_scans_per_sim_s`` = ``app_cpu_per_sim_s × naive_scans_per_cpu_s`` is
  the application's cost in host-independent units: divide it by another host's calibration
  to predict that host's share of a core (a Raspberry Pi 4 measures ~3–5× lower).
* ``app_per_sim_cpu`` — the application's CPU over the simulator's in the same run: a second,
  in-run calibration. The simulator's per-step work (physics, ray casting, IMU) is the same code
  from run to run, and it suffers the same contention as the application (another process on
  the sibling hardware thread slows both), which the pure-Python naive caster tracks less well.
  Valid for comparing runs while the simulator's own code is unchanged.

Options (``--set``): ``scenario=guided-tour`` (any ``curio sim`` scenario), ``duration=1800``,
``repeats=3``, ``parts=1`` (add each part's share of a core, every task metered: slower),
``web=0`` (skip the row with the hub).
"""

from __future__ import annotations

import asyncio
import os
import statistics
import tempfile
from typing import Any

from benchmarks.calibration import naive_scans_per_cpu_s
from curio.app import App
from curio.commands.bench import BenchOptions, prepare_kernels
from curio.core.clock import process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.core.cpu_meter import CpuMeter
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

SIM_LABELS = ("sim.", "arduino-emulator", "lidar-emulator")
HARNESS_LABELS = ("harness", "collector", "scenario:", "script@")


def _measure(scenario_name: str, overrides: list[str], web: bool, seed: int,
             duration_s: float, parts: bool) -> tuple[dict[str, Any], dict[str, float]]:
    """One run: the scenario report with the CPU figures, and the per-label CPU seconds."""
    meter = CpuMeter(None if parts else SIM_LABELS + HARNESS_LABELS)
    marks: dict[str, float] = {}

    async def started(_app: App) -> None:  # from here on the app runs: the window measured
        marks["cpu"] = process_cpu_time()
        marks.update({f"label:{k}": v for k, v in meter.seconds.items()})

    async def main() -> dict[str, Any]:
        meter.install()
        task = asyncio.create_task(
            run_scenario(get_scenario(scenario_name), cfg, args, on_app=started), name="harness")
        return await task

    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(REPO_ROOT / "config.toml",
                          [f'data_dir="{tmp}"', "web.port=0", "bt.speak=false", *overrides])
        args = ScenarioArgs(seed=seed, speed=None, duration_s=duration_s, web=web)
        cpu0, wall0 = process_cpu_time(), wall_perf_counter()
        report = asyncio.run(main())
        cpu_end, wall_end = process_cpu_time(), wall_perf_counter()
    window = {k: v - marks.get(f"label:{k}", 0.0) for k, v in meter.seconds.items()}
    report["_cpu_s"] = cpu_end - cpu0
    report["_wall_s"] = wall_end - wall0
    report["_window_cpu_s"] = cpu_end - marks["cpu"]
    return report, window


def _figures(report: dict[str, Any], window: dict[str, float]) -> dict[str, float]:
    sim_t = float(report["sim_time_s"])
    sim_cpu = sum(s for k, s in window.items() if k.startswith(SIM_LABELS))
    harness_cpu = sum(s for k, s in window.items() if k.startswith(HARNESS_LABELS))
    app_cpu = report["_window_cpu_s"] - sim_cpu - harness_cpu
    return {
        "wall_time_s": report["_wall_s"],
        "cpu_s": report["_cpu_s"],
        "rtf": sim_t / report["_wall_s"],
        "rtf_cpu": sim_t / report["_cpu_s"],
        "sim_cpu_s": sim_cpu,
        "harness_cpu_s": harness_cpu,
        "app_cpu_s": app_cpu,
        "app_cpu_per_sim_s": app_cpu / sim_t,
        "app_per_sim_cpu": app_cpu / sim_cpu if sim_cpu > 0 else float("nan"),
    }


def _subject(label: str, scenario_name: str, web: bool, opts: BenchOptions, duration_s: float,
             repeats: int, parts: bool) -> dict[str, Any]:
    runs = [_measure(scenario_name, [], web, opts.seed, duration_s, parts)
            for _ in range(repeats)]
    figs = [_figures(r, w) for r, w in runs]
    med = {k: statistics.median(f[k] for f in figs) for k in figs[0]}
    report = runs[0][0]
    row: dict[str, Any] = {
        "subject": label,
        "scenario": scenario_name,
        "success": all(r["success"] for r, _ in runs),
        "sim_time_s": report["sim_time_s"],
        "runs": repeats,
        "wall_time_s": round(med["wall_time_s"], 3),
        "rtf": round(med["rtf"], 2),
        "rtf_cpu": round(med["rtf_cpu"], 2),
        "sim_cpu_s": round(med["sim_cpu_s"], 3),
        "harness_cpu_s": round(med["harness_cpu_s"], 3),
        "app_cpu_s": round(med["app_cpu_s"], 3),
        "app_cpu_per_sim_s": round(med["app_cpu_per_sim_s"], 5),
        "app_pct_core": round(100 * med["app_cpu_per_sim_s"], 2),
        "app_pct_core_runs": [round(100 * f["app_cpu_per_sim_s"], 2) for f in figs],
        "app_per_sim_cpu": round(med["app_per_sim_cpu"], 3),
        "goals": f"{report['goals_reached']}/{report['goals_total']}",
        "collisions": report["collisions"],
        "localization_rmse_m": report["localization_rmse_m"],
    }
    if parts:
        sim_t = float(report["sim_time_s"])
        labels = sorted({k for _, w in runs for k in w})
        shares = {k: statistics.median(w.get(k, 0.0) for _, w in runs) / sim_t for k in labels}
        row["parts_pct_core"] = {k: round(100 * v, 3) for k, v in
                                 sorted(shares.items(), key=lambda kv: -kv[1]) if v > 1e-5}
    return row


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the scenario with and without the dashboard hub; one row each."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    scenario_name = str(opts.extra.get("scenario", "guided-tour"))
    duration_s = float(opts.extra.get("duration", 1800))
    repeats = max(1, int(opts.extra.get("repeats", 3)))
    parts = str(opts.extra.get("parts", "0")) not in ("0", "false", "")
    with_web = str(opts.extra.get("web", "1")) not in ("0", "false", "")
    # Untimed warm-up: imports and compiled-kernel loading are paid once per process, not by
    # whichever subject happens to run first.
    prepare_kernels()
    _measure(scenario_name, [], True, opts.seed, 5.0, False)
    calib = [naive_scans_per_cpu_s()]
    rows = []
    if with_web:
        rows.append(_subject("curio (full stack, web hub)", scenario_name, True, opts,
                             duration_s, repeats, parts))
        calib.append(naive_scans_per_cpu_s())
    rows.append(_subject("curio without web hub", scenario_name, False, opts, duration_s,
                         repeats, parts))
    calib.append(naive_scans_per_cpu_s())
    cal = statistics.median(calib)
    full = rows[0]["rtf"] or 0.0
    for row in rows:
        row["rtf_vs_full"] = round((row["rtf"] or 0.0) / full, 2) if full else None
        row["naive_scans_per_cpu_s"] = round(cal, 3)
        row["naive_scans_per_cpu_s_runs"] = [round(c, 3) for c in calib]
        row["app_naive_scans_per_sim_s"] = round(row["app_cpu_per_sim_s"] * cal, 5)
        row["load_avg_1m"] = round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None
    return rows
