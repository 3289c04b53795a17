"""Fleet benchmark: two rovers meet in the default building's narrowest doorway, many seeds.

``curio bench fleet [--pairs N] [--seed N] [--set transport=zenoh|memory] [--set procs=N]
[--set subjects=curio,no-intent,lidar]``

Each run is the fleet simulator's ``doorway`` scenario (``curio fleet sim --scenario doorway``):
two whole applications on one simulated clock, each with its own link, the workshop's 0.9 m
doorway between them, starts and start times jittered by the seed. ``--pairs N`` runs seeds
``seed .. seed+N-1`` (default 50) for each subject:

* ``curio`` — the fleet's traffic layer on (right of way, staging holds) and the other rover
  given to the people-aware controller as a moving obstacle with known intent
  (``fleet.traffic.predict_peers = true``, ``curio/fleet/intent.py``; off by default);
* ``curio, no intent`` (``no-intent``) — the traffic layer without that prediction
  (``fleet.traffic.predict_peers = false``, the default: the controller sees the other rover
  only as the lidar and the people tracker do);
* ``lidar only`` — the same two rovers with ``fleet.traffic.enabled = false``: nothing but
  their lidars, costmaps and safety stages keep them apart (what two rovers without a fleet
  layer would do).

Rows: ``runs``, ``success_rate`` (both goals reached in 180 s: no deadlock),
``rover_rover_collisions`` (total), ``runs_with_collision``, ``encounters`` (give-way
decisions), ``longest_standoff_s`` (the longest a rover held for the other, any run),
``p95_standoff_s``, ``median_time_to_both_s``, ``link_bytes_per_s`` (mean per rover),
``wall_time_s``. Targets: success 100 %, zero collisions, longest standoff ≤ 10 s.
``--set subjects=`` picks some of them (default all three). Runs go through a process pool
(one per core, ``--set procs=N`` to change); the transport is
the in-process one unless ``--set transport=zenoh`` (the same runs, with sockets).
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import statistics
import tempfile
import time
from typing import Any

from curio.commands.bench import BenchOptions
from curio.core.config import load_config

SUBJECTS = {"curio": ("curio", True, True), "no-intent": ("curio, no intent", True, False),
            "lidar": ("lidar only", False, False)}


def _run_job(job: tuple[str, int, bool, bool, str, str]) -> dict[str, Any]:
    subject, seed, traffic, intent, transport, tmp = job
    from curio.scenarios.fleet import get_fleet_scenario
    from curio.scenarios.fleet.base import FleetArgs, run_fleet

    cfg = load_config(None, [f'data_dir="{tmp}/{subject.replace(" ", "_").replace(",", "")}'
                             f'-{seed}"',
                             f"fleet.traffic.enabled={'true' if traffic else 'false'}",
                             f"fleet.traffic.predict_peers={'true' if intent else 'false'}"])
    report = asyncio.run(run_fleet(get_fleet_scenario("doorway"), cfg,
                                   FleetArgs(seed=seed, transport=transport)))  # type: ignore[arg-type]
    m = report["metrics"]
    return {"subject": subject, "seed": seed, "success": report["success"],
            "collisions": m["rover_rover_collisions"], "encounters": m["rover_rover_encounters"],
            "standoffs": m["standoffs_s"], "time": m.get("time_to_both_s"),
            "bytes": statistics.mean(x["bytes_per_s"] for x in m["link"]),
            "failure": report["failure"]}


def _summarise(subject: str, results: list[dict[str, Any]], wall_s: float) -> dict[str, Any]:
    stand = sorted(s for r in results for s in r["standoffs"])
    times = [r["time"] for r in results if r["time"] is not None]
    return {
        "subject": subject, "runs": len(results),
        "success_rate": round(sum(r["success"] for r in results) / max(1, len(results)), 3),
        "rover_rover_collisions": sum(r["collisions"] for r in results),
        "runs_with_collision": sum(1 for r in results if r["collisions"]),
        "encounters": sum(r["encounters"] for r in results),
        "longest_standoff_s": round(max(stand, default=0.0), 2),
        "p95_standoff_s": round(stand[int(0.95 * (len(stand) - 1))], 2) if stand else 0.0,
        "median_time_to_both_s": round(statistics.median(times), 1) if times else None,
        "link_bytes_per_s": round(statistics.mean(r["bytes"] for r in results), 1),
        "failed_seeds": [r["seed"] for r in results if not r["success"]],
        "wall_time_s": round(wall_s, 1),
    }


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the benchmark and return its rows."""
    n = opts.pairs or 50
    transport = str(opts.extra.get("transport", "memory"))
    procs = int(opts.extra.get("procs", os.cpu_count() or 1))
    wanted = str(opts.extra.get("subjects", ",".join(SUBJECTS))).split(",")
    unknown = [w for w in wanted if w not in SUBJECTS]
    if unknown:
        raise ValueError(f"subjects: {', '.join(unknown)} unknown; allowed: "
                         f"{', '.join(SUBJECTS)}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="curio-bench-fleet-") as tmp:
        for key in wanted:
            subject, traffic, intent = SUBJECTS[key]
            jobs = [(subject, opts.seed + i, traffic, intent, transport, tmp) for i in range(n)]
            t0 = time.perf_counter()
            ctx = multiprocessing.get_context("fork")
            with ctx.Pool(procs) as pool:
                results = list(pool.imap_unordered(_run_job, jobs, chunksize=1))
            rows.append(_summarise(subject, sorted(results, key=lambda r: r["seed"]),
                                   time.perf_counter() - t0))
    return rows
