"""The flight recorder's cost: CPU and disk at full sensor rates on a simulated tour, and the
whole stack's real-time factor with the recorder on beside off.

Each subject runs the same scenario (``guided-tour`` by default: the tour guide visits the five
stops of the shipped config, then goes home) on simulated time, on one core, as
``bench_stack`` does — every sensor at its configured rate (lidar 10 Hz, IMU 100 Hz, wheels
30 Hz, EKF 50 Hz, ...). The recorder writes the run to an MCAP file (``curio sim --record``);
on a simulated clock its queue never drops (the loop waits for the writer), so the figures are
those of a complete recording.

Figures (per simulated second, so they are what the rover pays at real time):

* ``recorder_cpu_fraction`` — CPU seconds of the writer thread (encoding, compression, file
  writes) per second of run: the share of one core the recorder takes on the rover;
* ``cpu_overhead_fraction`` — the whole process's extra CPU against the same run unrecorded,
  per second of run (the writer plus the bus tap and the GIL hand-overs);
* ``disk_mb_per_h`` — the file's size per hour of touring (targets: ≤ 3 % of a core, ≤ 200
  MB/h);
* ``rtf`` / ``rtf_cpu`` — simulated seconds per wall / CPU second, as in ``bench_stack``
  (target ≥ 20× with the recorder on); ``rtf_vs_off`` — against the unrecorded run.

Options (``--set``): ``scenario=guided-tour``, ``duration=1800``.
"""

from __future__ import annotations

import asyncio
import os
import tempfile
from pathlib import Path
from typing import Any

from curio.commands.bench import BenchOptions, prepare_kernels
from curio.core.clock import process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario


def _one(label: str, scenario_name: str, record: bool, overrides: list[str], seed: int,
         duration_s: float) -> dict[str, Any]:
    apps: list[Any] = []

    async def keep(app: Any) -> None:
        apps.append(app)

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.mcap"
        cfg = load_config(REPO_ROOT / "config.toml",
                          [f'data_dir="{tmp}"', "bt.speak=false", *overrides])
        args = ScenarioArgs(seed=seed, speed=None, duration_s=duration_s,
                            record=path if record else None)
        cpu0, wall0 = process_cpu_time(), wall_perf_counter()
        report = asyncio.run(run_scenario(get_scenario(scenario_name), cfg, args, on_app=keep))
        cpu, wall = process_cpu_time() - cpu0, wall_perf_counter() - wall0
        size = path.stat().st_size if record else 0
    sim = report["sim_time_s"]
    row: dict[str, Any] = {
        "subject": label, "scenario": scenario_name, "success": report["success"],
        "sim_time_s": sim, "wall_time_s": round(wall, 3),
        "rtf": round(sim / wall, 2) if wall > 0 else None,
        "rtf_cpu": round(sim / cpu, 2) if cpu > 0 else None, "cpu_s": round(cpu, 3),
    }
    rec = apps[0].recorder if apps else None
    if record and rec is not None and sim > 0:
        written = sum(rec.written.values())
        row.update({
            "recorder_cpu_fraction": round(rec.writer_cpu_s / sim, 4),
            "disk_mb_per_h": round(size / 1e6 / sim * 3600, 1),
            "file_mb": round(size / 1e6, 2),
            "messages_per_s": round(written / sim, 1),
            "dropped": rec.queue.dropped_total,
            "skipped": sum(rec.skipped.values()),
        })
    return row


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """The scenario unrecorded, recorded (zstd) and recorded with lz4; one row each."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    scenario_name = str(opts.extra.get("scenario", "guided-tour"))
    duration_s = float(opts.extra.get("duration", 1800))
    prepare_kernels()
    _one("warm-up", scenario_name, True, [], opts.seed, 5.0)  # imports, compiled kernels
    off = _one("curio, recorder off", scenario_name, False, [], opts.seed, duration_s)
    rows = [
        off,
        _one("curio, recorder on (zstd, the default)", scenario_name, True, [], opts.seed,
             duration_s),
        _one("curio, recorder on (lz4)", scenario_name, True, ["record.compression=lz4"],
             opts.seed, duration_s),
    ]
    for row in rows[1:]:
        row["cpu_overhead_fraction"] = round((row["cpu_s"] - off["cpu_s"]) / row["sim_time_s"],
                                             4)
        row["rtf_vs_off"] = round(row["rtf"] / off["rtf"], 2) if off["rtf"] else None
    return rows
