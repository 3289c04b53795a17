"""Crowd benchmark: the guided tour and random goto pairs among 0, 5, 10 and 20 visitors,
the people-aware controller and the baseline side by side.

``curio bench crowd [--pairs N] [--seed N] [--map YAML] [--set KEY=VALUE]...``

Every run is the ``crowd`` scenario (``curio sim crowd``): the whole application on simulated
time with a social-force crowd (:mod:`curio.sim.crowd`). The same jobs — a map, a kind (tour
or goto), a seed and for goto a start/goal pair (free, 3–15 m apart, joined in the static
costmap, away from scripted walkers: :func:`benchmarks.bench_nav.pick_pairs`) — run for every
visitor count and both controllers, so the figures are paired:

* **aware** — ``people.aware = true``: tracked people predicted in the controller, walking
  people kept out of the costmap, the polite guide (docs/people.md);
* **baseline** — ``people.aware = false``: today's controller, people are costmap marks.

Options (``--set``): ``counts=0,5,10,20``; ``controllers=aware,baseline``; ``tours=0.1`` (the
share of runs that are guided tours); ``maps=building,curio_shapes,willow_garage,depot``
(names of the default building and of ``../shared/maps`` folders; ``--map`` runs one map);
``procs=2`` (worker processes); ``rtf=1`` (also time the whole stack on one core: the
guided tour with ``rtf_visitors=20`` visitors); ``standing=1`` (the reference row "a rover
standing still": the same visitors, no stack, round a rover that never moves at the start
of each of the first 100 goto jobs for 120 s — how close the visitors come by themselves).
``--pairs N`` is the number of runs per visitor count and controller (default 200; half on
the building, the rest spread over the shared maps).

Rows: one per controller and visitor count with ``runs``, ``success_rate``,
``collisions_rover_at_fault`` (and ``runs_with_rover_fault``), ``collisions_person_at_fault``,
``min_person_distance_m`` (over all runs) and ``median_min_person_distance_m`` (of runs with
an encounter), ``time_below_0_3m_s`` (mean per run), ``encounters``,
``encounters_ok_fraction`` (minimum ≥ 0.3 m; also while the rover moved, and counting as
fine the encounters below 0.3 m the person made — the rover was not closing in on them when
they were nearest), ``mean_time_s``
(successful runs), ``time_vs_empty`` (mean time of the runs that succeeded both here and with
no visitors, over the same runs' time with none), ``tracks_mota`` / ``tracks_motp_m`` /
``tracks_velocity_rmse_mps`` (pooled CLEAR MOT counts), ``excuse_me_per_run``,
``help_requests_per_run``, ``rtf_cpu`` and the targets met; then the ratios aware / baseline,
per map and kind breakdowns, the first failed runs and the one-core real-time factor.

Targets (issue 14): with 10 visitors success ≥ 98 %, zero rover-at-fault collisions, minimum
distance ≥ 0.3 m in ≥ 99 % of encounters, mean time ≤ 1.4 × the empty building's; with 20
visitors success ≥ 95 %; the whole stack with 20 visitors ≥ 20× real time on one core.
"""

from __future__ import annotations

import asyncio
import math
import multiprocessing
import os
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from curio.commands.bench import BenchOptions, prepare_kernels
from curio.core.clock import process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.core.errors import SetupError
from curio.core.geometry import Pose2D

SHARED_MAPS = REPO_ROOT.parent / "shared" / "maps"
BUILDING = REPO_ROOT / "maps" / "curio_building.yaml"
MAP_FILES = {
    "building": BUILDING,
    "curio_shapes": SHARED_MAPS / "curio_shapes" / "shapes_footprint.yaml",
    "willow_garage": SHARED_MAPS / "willow_garage" / "willow-full-0.05.yaml",
    "depot": SHARED_MAPS / "depot" / "depot.yaml",
    "warehouse": SHARED_MAPS / "warehouse" / "warehouse.yaml",
    "tb3_sandbox": SHARED_MAPS / "tb3_sandbox" / "tb3_sandbox.yaml",
}
DEFAULT_MAPS = ("building", "curio_shapes", "willow_garage", "depot")
MOT_KEYS = ("tracks_objects", "tracks_misses", "tracks_false_positives", "tracks_id_switches")


def _opt_list(opts: BenchOptions, key: str, default: str) -> list[str]:
    return [v.strip() for v in str(opts.extra.get(key, default)).split(",") if v.strip()]


def _opt_counts(opts: BenchOptions) -> list[int]:
    text = str(opts.extra.get("counts", "0,5,10,20"))
    try:
        counts = [int(c) for c in text.split(",") if c.strip()]
    except ValueError:
        counts = []
    if not counts or not all(0 <= c <= 100 for c in counts):
        raise SetupError(f"bench crowd: counts= takes visitor counts 0..100 like 0,5,10,20, "
                         f"got '{text}'")
    return counts


# --- jobs ---------------------------------------------------------------------------------------
def _maps(opts: BenchOptions) -> list[tuple[str, Path]]:
    if opts.map_yaml:
        path = Path(opts.map_yaml).resolve()
        return [(path.stem, path)]
    out = []
    for name in _opt_list(opts, "maps", ",".join(DEFAULT_MAPS)):
        if name not in MAP_FILES:
            raise SetupError(f"bench crowd: unknown map '{name}' in maps=; known: "
                             f"{', '.join(sorted(MAP_FILES))}")
        if MAP_FILES[name].is_file():
            out.append((name, MAP_FILES[name]))
    return out


def make_jobs(opts: BenchOptions) -> list[dict[str, Any]]:
    """The runs (without visitor count and controller): map, kind, seed, start and goal."""
    from benchmarks.bench_nav import pick_pairs

    runs = opts.pairs or 200
    maps = _maps(opts)
    tours = round(runs * float(opts.extra.get("tours", 0.1)))
    # Half the runs on the building (when it is one of the maps), the rest spread evenly.
    share: dict[str, int] = {}
    names = [name for name, _ in maps]
    if "building" in names and len(names) > 1:
        share["building"] = runs // 2 + runs % 2
        rest = [n for n in names if n != "building"]
        for k, n in enumerate(rest):
            share[n] = (runs - share["building"]) // len(rest) + (
                1 if k < (runs - share["building"]) % len(rest) else 0)
    else:
        for k, n in enumerate(names):
            share[n] = runs // len(names) + (1 if k < runs % len(names) else 0)
    jobs: list[dict[str, Any]] = []
    for name, path in maps:
        n = share[name]
        n_tour = round(tours * n / runs) if runs else 0
        seed0 = opts.seed * 100_000 + len(jobs)
        for i in range(n_tour):
            jobs.append({"map": name, "world": str(path), "kind": "tour", "seed": seed0 + i})
        pairs = pick_pairs(str(path), n - n_tour, seed0 + n_tour)
        for i, (start, goal) in enumerate(pairs):
            jobs.append({"map": name, "world": str(path), "kind": "goto",
                         "seed": seed0 + n_tour + i, "start": start.as_tuple(),
                         "goal": (goal.x, goal.y)})
    return jobs


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """One crowd run in a worker process."""
    from curio.scenarios import get_scenario
    from curio.scenarios.base import ScenarioArgs, run_scenario

    data = Path(tempfile.gettempdir()) / f"curio-bench-crowd-{os.getpid()}"
    cfg = load_config(REPO_ROOT / "config.toml", [
        "web.enabled=false", f'data_dir="{data}"', f'sim.world="{job["world"]}"',
        "bt.speak=false", "eventlog.enabled=false",
        f"people.aware={'true' if job['controller'] == 'aware' else 'false'}"])
    if job["kind"] == "goto":
        start, goal = Pose2D(*job["start"]), job["goal"]
        d = math.hypot(goal[0] - start.x, goal[1] - start.y)
        args = ScenarioArgs(start=start.as_tuple(), goal=(goal[0], goal[1], None),
                            seed=job["seed"], visitors=job["visitors"],
                            duration_s=90.0 + 6.0 * d / cfg.nav.controller.max_speed_mps)
    else:
        args = ScenarioArgs(seed=job["seed"], visitors=job["visitors"], duration_s=1500.0)
    cpu0 = process_cpu_time()
    report = asyncio.run(run_scenario(get_scenario("crowd"), cfg, args))
    m = report["metrics"]
    out = {k: job[k] for k in ("map", "kind", "seed", "visitors", "controller")}
    out.update(success=bool(report["success"]), failure=report.get("failure"),
               sim_time_s=report["sim_time_s"], wall_time_s=report["wall_time_s"],
               cpu_s=process_cpu_time() - cpu0, nav_time_s=m.get("nav_time_s"),
               error_code=m.get("error_code"))
    for key in ("collisions_rover_at_fault", "collisions_rover_with_people",
                "collisions_person_at_fault", "min_person_distance_m",
                "min_person_distance_moving_m", "time_below_0_3m_s", "encounters",
                "encounters_ok", "encounters_ok_fraction", "encounters_ok_moving_fraction",
                "encounters_below_by_person",
                "excuse_me", "help_requests", *MOT_KEYS, "tracks_motp_m",
                "tracks_velocity_rmse_mps"):
        out[key] = m.get(key)
    return out


# --- summaries ----------------------------------------------------------------------------------
def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def summarise(label: dict[str, Any], rs: list[dict[str, Any]],
              empty: dict[tuple[Any, ...], dict[str, Any]] | None) -> dict[str, Any]:
    """One row of figures for the results ``rs``; ``empty`` maps a job key to the same job's
    run with no visitors (for ``time_vs_empty``)."""
    ok = [r for r in rs if r["success"]]
    mins = [r["min_person_distance_m"] for r in rs if r["min_person_distance_m"] is not None]
    enc = sum(r["encounters"] or 0 for r in rs)
    enc_ok = sum(r["encounters_ok"] or 0 for r in rs)
    enc_ok_moving = sum((r["encounters_ok_moving_fraction"] or 0.0) * (r["encounters"] or 0)
                        for r in rs)
    mot = {k: sum(r[k] or 0 for r in rs) for k in MOT_KEYS}
    matched = mot["tracks_objects"] - mot["tracks_misses"]
    motp = [r["tracks_motp_m"] for r in rs if r["tracks_motp_m"] is not None]
    vel = [r["tracks_velocity_rmse_mps"] for r in rs if r["tracks_velocity_rmse_mps"] is not None]
    ratio = None
    if empty is not None:
        both = [(r, empty.get(_key(r))) for r in ok]
        both = [(r, e) for r, e in both if e is not None and e["success"] and e["nav_time_s"]]
        if both:
            ratio = (float(np.mean([r["nav_time_s"] for r, _ in both]))
                     / float(np.mean([e["nav_time_s"] for _, e in both])))
    sim = sum(r["sim_time_s"] for r in rs)
    cpu = sum(r["cpu_s"] for r in rs)
    return {
        **label, "runs": len(rs),
        "success_rate": len(ok) / len(rs) if rs else None,
        "collisions_rover_at_fault": sum(r["collisions_rover_at_fault"] or 0 for r in rs),
        "runs_with_rover_fault": sum(1 for r in rs if r["collisions_rover_at_fault"]),
        "collisions_person_at_fault": sum(r["collisions_person_at_fault"] or 0 for r in rs),
        "min_person_distance_m": min(mins) if mins else None,
        "median_min_person_distance_m": float(np.median(mins)) if mins else None,
        "time_below_0_3m_s": _mean([r["time_below_0_3m_s"] or 0.0 for r in rs]),
        "encounters": enc,
        "encounters_ok_fraction": enc_ok / enc if enc else None,
        "encounters_ok_moving_fraction": enc_ok_moving / enc if enc else None,
        "encounters_ok_or_by_person_fraction": (enc_ok + sum(
            r["encounters_below_by_person"] or 0 for r in rs)) / enc if enc else None,
        "mean_time_s": _mean([r["nav_time_s"] for r in ok if r["nav_time_s"]]),
        "time_vs_empty": ratio,
        "tracks_mota": (1.0 - (mot["tracks_misses"] + mot["tracks_false_positives"]
                               + mot["tracks_id_switches"]) / mot["tracks_objects"])
        if mot["tracks_objects"] else None,
        "tracks_motp_m": _mean(motp) if matched > 0 else None,
        "tracks_velocity_rmse_mps": float(np.sqrt(np.mean(np.square(vel)))) if vel else None,
        "excuse_me_per_run": _mean([r["excuse_me"] or 0 for r in rs]),
        "help_requests_per_run": _mean([r["help_requests"] or 0 for r in rs]),
        "rtf_cpu": round(sim / cpu, 1) if cpu > 0 else None,
        "failures": dict(Counter(str(r["error_code"] or r["failure"])[:48]
                                 for r in rs if not r["success"])),
    }


def _key(r: dict[str, Any]) -> tuple[Any, ...]:
    return (r["controller"], r["map"], r["kind"], r["seed"])


def targets(row: dict[str, Any]) -> str:
    """The issue's targets for this row's visitor count: which are met."""
    n = row.get("visitors")
    out = []
    if n == 10:
        checks = {
            "success>=98%": (row["success_rate"] or 0.0) >= 0.98,
            "no rover-at-fault": row["collisions_rover_at_fault"] == 0,
            "0.3m in >=99% of encounters": (row["encounters_ok_fraction"] or 0.0) >= 0.99,
            "time<=1.4x empty": row["time_vs_empty"] is not None
            and row["time_vs_empty"] <= 1.4,
        }
        out = [f"{k}: {'met' if v else 'MISSED'}" for k, v in checks.items()]
    elif n == 20:
        out = [f"success>=95%: {'met' if (row['success_rate'] or 0.0) >= 0.95 else 'MISSED'}"]
    return "; ".join(out)


def _ratios(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """aware / baseline for each visitor count, for the figures where a ratio means something."""
    out = []
    by = {(r["controller"], r["visitors"]): r for r in rows}
    keys = ("success_rate", "collisions_rover_at_fault", "collisions_person_at_fault",
            "time_below_0_3m_s", "encounters_ok_fraction", "mean_time_s", "time_vs_empty",
            "median_min_person_distance_m")
    for (ctrl, n), row in sorted(by.items(), key=lambda kv: kv[0][1]):
        base = by.get(("baseline", n))
        if ctrl != "aware" or base is None:
            continue
        ratio: dict[str, Any] = {"subject": "ratio aware/baseline", "visitors": n}
        for k in keys:
            a, b = row.get(k), base.get(k)
            ratio[k] = (a / b if b else None) if isinstance(a, (int, float)) and isinstance(
                b, (int, float)) else None
        out.append(ratio)
    return out


# --- the standing rover: what the visitors do by themselves ----------------------------------
STANDING_S = 120.0
STANDING_STEP_S = 0.05
STANDING_RUNS = 100  # per visitor count (the first goto jobs)


def standing_job(job: dict[str, Any]) -> dict[str, Any]:
    """The crowd alone (no stack) round a rover that stands still at the goto job's start for
    ``STANDING_S``: its encounters, as the crowd scenario counts them."""
    from curio.estimation.maps import load_map
    from curio.people.metrics import Proximity
    from curio.robot import RobotModel
    from curio.sim.crowd import Crowd, RoverState
    from curio.sim.objects import circle_hits_polygon

    cfg = load_config(REPO_ROOT / "config.toml", [
        f'sim.world="{job["world"]}"', f"sim.crowd.visitors={job['visitors']}",
        f"sim.seed={job['seed']}"])
    pose = Pose2D(*job["start"])
    footprint = RobotModel.from_config(cfg.robot).footprint
    crowd = Crowd.for_world(load_map(cfg.resolve(cfg.sim.world)), cfg, pose)
    prox = Proximity(footprint)
    if crowd is None:
        return {**job, **prox.summary()}
    outline = [pose.transform_point(x, y) for x, y in footprint]
    rover = RoverState(pose, 0.0, 0.0, footprint)
    ids = [v.vid for v in crowd.visitors]
    radii = np.full(len(ids), crowd.radius_m)
    t = 0.0
    while t < STANDING_S:
        crowd.step(STANDING_STEP_S, rover,
                   lambda x, y, r: circle_hits_polygon(x, y, r, outline))
        t += STANDING_STEP_S
        prox.add(t, pose, 0.0, ids, crowd.pos, radii)
    return {**job, **prox.summary()}


def standing_rows(base_jobs: list[dict[str, Any]], counts: list[int],
                  procs: int) -> list[dict[str, Any]]:
    """A reference for the distance figures: the same visitors round a rover that never moves
    (at the start of each of the first ``STANDING_RUNS`` goto jobs, ``STANDING_S`` each), per
    visitor count."""
    gotos = [j for j in base_jobs if j["kind"] == "goto"][:STANDING_RUNS]
    jobs = [{**j, "visitors": n} for j in gotos for n in counts if n > 0]
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(procs, maxtasksperchild=50) as pool:
        results = list(pool.imap_unordered(standing_job, jobs, chunksize=4))
    rows = []
    for n in sorted({r["visitors"] for r in results}):
        rs = [r for r in results if r["visitors"] == n]
        enc = sum(r["encounters"] for r in rs)
        ok = sum(r["encounters_ok"] for r in rs)
        rows.append({"subject": "a rover standing still (the crowd alone)", "visitors": n,
                     "runs": len(rs), "seconds_each": STANDING_S, "encounters": enc,
                     "encounters_ok_fraction": ok / enc if enc else None,
                     "time_below_0_3m_s": _mean([r["time_below_0_3m_s"] for r in rs])})
    return rows


# --- the one-core real-time factor ------------------------------------------------------------
def rtf_row(visitors: int, seed: int) -> dict[str, Any]:
    """The whole stack (default config, dashboard hub on, no clients, people-aware) running
    the ``guided-tour`` scenario among ``visitors`` visitors, pinned to one core: simulated
    seconds per wall second (``rtf``) and per CPU second of the process (``rtf_cpu``, the same
    with other load on the machine factored out). The crowd scenario's own measuring is not
    part of the stack and not timed."""
    from curio.scenarios import get_scenario
    from curio.scenarios.base import ScenarioArgs, run_scenario

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    prepare_kernels()
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(REPO_ROOT / "config.toml",
                          [f'data_dir="{tmp}"', "web.port=0", "bt.speak=false"])
        args = ScenarioArgs(seed=seed, visitors=visitors, duration_s=1800.0, web=True)
        asyncio.run(run_scenario(get_scenario("guided-tour"), cfg, ScenarioArgs(
            seed=seed, visitors=visitors, duration_s=5.0)))  # warm-up (imports, kernels)
        cpu0, wall0 = process_cpu_time(), wall_perf_counter()
        report = asyncio.run(run_scenario(get_scenario("guided-tour"), cfg, args))
        cpu, wall = process_cpu_time() - cpu0, wall_perf_counter() - wall0
    return {"subject": f"curio whole stack, guided tour, {visitors} visitors, one core",
            "success": report["success"], "sim_time_s": report["sim_time_s"],
            "wall_time_s": round(wall, 2), "rtf": round(report["sim_time_s"] / wall, 1),
            "rtf_cpu": round(report["sim_time_s"] / cpu, 1), "target": ">= 20x",
            "met": report["sim_time_s"] / wall >= 20.0}


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the benchmark and return its rows."""
    counts = _opt_counts(opts)
    controllers = _opt_list(opts, "controllers", "aware,baseline")
    if not controllers or not set(controllers) <= {"aware", "baseline"}:
        raise SetupError("bench crowd: controllers= takes aware and/or baseline, got "
                         f"'{opts.extra.get('controllers')}'")
    procs = max(1, int(opts.extra.get("procs", min(2, os.cpu_count() or 1))))
    base_jobs = make_jobs(opts)
    jobs = [{**j, "visitors": n, "controller": c}
            for j in base_jobs for n in counts for c in controllers]
    t0 = time.perf_counter()
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(procs, maxtasksperchild=50) as pool:
        results = list(pool.imap_unordered(run_job, jobs, chunksize=1))
    wall = time.perf_counter() - t0
    rows = []
    for c in controllers:
        empty = {_key(r): r for r in results if r["controller"] == c and r["visitors"] == 0}
        for n in counts:
            rs = [r for r in results if r["controller"] == c and r["visitors"] == n]
            row = summarise({"subject": f"curio {c}", "controller": c, "visitors": n}, rs,
                            empty if 0 in counts else None)
            row["targets"] = targets(row)
            rows.append(row)
    rows += _ratios(rows)
    for c in controllers:
        for n in counts:
            for name, kind in sorted({(r["map"], r["kind"]) for r in results}):
                rs = [r for r in results if r["controller"] == c and r["visitors"] == n
                      and r["map"] == name and r["kind"] == kind]
                if rs:
                    rows.append(summarise({"subject": f"curio {c}", "visitors": n,
                                           "map": name, "kind": kind}, rs, None))
    failed = [r for r in results if not r["success"]]
    if failed:
        rows.append({"subject": "failed runs (first 20)", "failures": [
            {k: r[k] for k in ("controller", "visitors", "map", "kind", "seed", "failure")}
            for r in failed[:20]]})
    if str(opts.extra.get("standing", "1")) not in ("0", "false", "no"):
        rows += standing_rows(base_jobs, counts, procs)
    rows.append({"subject": "bench", "jobs": len(jobs), "procs": procs,
                 "wall_time_s": round(wall, 1)})
    if str(opts.extra.get("rtf", "1")) not in ("0", "false", "no"):
        rows.append(rtf_row(int(opts.extra.get("rtf_visitors", 20)), opts.seed))
    return rows
