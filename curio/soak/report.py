"""The soak's report: JSON (``--report PATH``) and the summary table.

Top level: ``command`` (``soak``), ``seed``, ``hours``, ``clients``, ``success``, ``failure``,
``checks`` (``[{name, ok, detail}]``), ``metrics`` (DESIGN.md's contract: ``collisions``,
split as in ``curio sim crowd`` into ``collisions_rover_at_fault`` (judged: must be 0) and
``collisions_person_at_fault`` (a visitor walked into the rover while it was not moving towards
them), ``commands_lost``, ``faults_injected``, ``faults_recovered``, ``rss_growth_mb_per_h``, and
more), ``faults`` (per kind and each one), ``commands`` (the ledger), ``restarts``, ``files``,
``resources``, ``timing``, ``time`` (building hours, simulated seconds actually run, the
time-lapse, wall time, real-time factors), ``load`` (the machine's load average), ``disk``
and ``notes``.

Budgets (this machine; a Raspberry Pi 4 is 3–5× slower per core):

* navigation cycle (``NavigatorNode.step``: navigator policies and local controller) CPU
  p99 ≤ ``NAV_P99_BUDGET_S`` (a quarter of its 100 ms period);
* safety step CPU p99 ≤ ``SAFETY_P99_BUDGET_S`` (a tenth of its 50 ms period), and its rate
  in every sample window ≥ ``RATE_FLOOR`` × ``nav.safety.rate_hz`` with no gap between two
  steps over two periods (injected loop stalls excepted, and counted apart);
* resident memory growth after warm-up ≤ ``RSS_BUDGET_MB_PER_H`` per simulated hour: the
  least-squares slope of the samples taken after the warm-up (``WARM_UP_FIRST_S`` of the
  first run, ``WARM_UP_LATER_S`` of each restarted one), per hour of simulated time actually
  run (the time-lapse is not counted: nothing runs then); judged only when those samples span
  at least ``RSS_MIN_SPAN_H`` (a shorter slope is the allocator's noise: it is reported, the
  check says "not judged");
* file descriptors and threads: no growth after warm-up (``FD_SLACK``, ``THREAD_SLACK``);
* queues: the longest bus subscriber queue, the dashboard clients' queues and the recorder's
  queue stay under ``QUEUE_LIMIT`` messages at every sample.
"""

from __future__ import annotations

import math
import statistics
from typing import TYPE_CHECKING, Any

from curio.core.clock import wall_perf_counter
from curio.soak.plan import KINDS
from curio.soak.verdict import (
    NAV_P99_BUDGET_S,
    SAFETY_P99_BUDGET_S,
    checks_of,
)

if TYPE_CHECKING:  # pragma: no cover
    from curio.soak.orchestrator import Orchestrator

__all__ = ["build_report", "format_table"]

# The warm-up left out: 10 min of the first run and 5 min of each restarted one. A process
# settles later than that on the full campaign (15-40 active minutes: its first help episodes
# and tours; docs/reliability.md, "Memory: what the rover keeps"), so a day with 13 restarts is
# judged largely on processes still settling; the windows are not widened to hide it. A slope
# over 20 min of samples still swings by several MB/h either way, hence RSS_MIN_SPAN_H.
WARM_UP_FIRST_S = 600.0
WARM_UP_LATER_S = 300.0
RTF_TARGET = 20.0


def _stats(values: list[float]) -> dict[str, Any]:
    if not values:
        return {"n": 0}
    ordered = sorted(values)
    p90 = ordered[min(len(ordered) - 1, math.ceil(0.9 * len(ordered)) - 1)]
    return {"n": len(values), "median": round(statistics.median(values), 3),
            "p90": round(p90, 3), "max": round(max(values), 3)}


def _fault_table(o: Orchestrator) -> dict[str, Any]:
    results = sorted(o.obs.faults.values(), key=lambda r: int(r["id"]))
    by_kind: dict[str, dict[str, Any]] = {}
    for kind in KINDS:
        mine = [r for r in results if r.get("kind") == kind]
        planned = sum(1 for f in o.plan if f.kind == kind)
        row: dict[str, Any] = {"planned": planned, "judged": len(mine)}
        for outcome in ("recovered", "stopped_safely", "failed", "not_injected"):
            row[outcome] = sum(1 for r in mine if r.get("outcome") == outcome)
        row["detected_health"] = sum(1 for r in mine if r.get("detected_health_s") is not None)
        row["detected_log"] = sum(1 for r in mine if r.get("detected_log_s") is not None)
        row["detect_s"] = _stats([r["detected_health_s"] for r in mine
                                  if r.get("detected_health_s") is not None])
        row["recover_s"] = _stats([r["recover_s"] for r in mine
                                   if r.get("recover_s") is not None])
        row["outage_s"] = _stats([r["outage_s"] for r in mine if r.get("outage_s") is not None])
        by_kind[kind] = row
    return {"by_kind": by_kind, "list": results}


def _growth(samples: list[dict[str, Any]], key: str) -> tuple[float | None, dict[str, Any]]:
    """Pooled least-squares slope of ``key`` per simulated hour after warm-up (per-run
    intercepts, so a restart's fresh process does not count as a drop)."""
    runs: dict[int, list[tuple[float, float]]] = {}
    first: dict[int, float] = {}
    for s in samples:
        boot = int(s.get("boot", 0))
        t = float(s["sim_s"])
        first.setdefault(boot, t)
        warm = WARM_UP_FIRST_S if boot == 0 else WARM_UP_LATER_S
        value = s.get(key)
        if t - first[boot] >= warm and isinstance(value, int | float) and math.isfinite(value):
            runs.setdefault(boot, []).append((t / 3600.0, float(value)))
    num = den = 0.0
    spans = {}
    for boot, pts in runs.items():
        if len(pts) < 3:
            continue
        mx = sum(p[0] for p in pts) / len(pts)
        my = sum(p[1] for p in pts) / len(pts)
        num += sum((x - mx) * (y - my) for x, y in pts)
        den += sum((x - mx) ** 2 for x, _ in pts)
        ys = [y for _, y in pts]
        spans[str(boot)] = {"samples": len(pts), "hours": round(pts[-1][0] - pts[0][0], 3),
                            "min": round(min(ys), 2), "max": round(max(ys), 2),
                            "first": round(ys[0], 2), "last": round(ys[-1], 2)}
    return (num / den if den > 0 else None), spans


def _resources(o: Orchestrator) -> dict[str, Any]:
    res = o.obs.res
    rss, rss_runs = _growth(res, "rss_mb")
    fds, fd_runs = _growth(res, "fds")
    threads, thread_runs = _growth(res, "threads")
    return {
        "samples": len(res),
        "rss_growth_mb_per_h": None if rss is None else round(rss, 3), "rss_runs": rss_runs,
        "rss_span_h": round(sum(float(v["hours"]) for v in rss_runs.values()), 3),
        "rss_max_mb": round(max((float(s["rss_mb"]) for s in res), default=0.0), 1),
        "fd_growth_per_h": None if fds is None else round(fds, 3), "fd_runs": fd_runs,
        "thread_growth_per_h": None if threads is None else round(threads, 3),
        "thread_runs": thread_runs,
        "bus_backlog_max": max((int(s.get("bus_backlog_max", 0)) for s in res), default=0),
        "bus_backlog_worst_topic": max(res, key=lambda s: s.get("bus_backlog_max", 0),
                                       default={}).get("bus_backlog_topic"),
        "web_reliable_max": max((int(s.get("web", {}).get("reliable_max", 0)) for s in res),
                                default=0),
        "web_streams_max": max((int(s.get("web", {}).get("streams_max", 0)) for s in res),
                               default=0),
        "recorder_queue_max": max((int(s.get("recorder_queue", 0)) for s in res), default=0),
        "eventlog_queue_max": max((int(s.get("eventlog_queue", 0)) for s in res), default=0),
    }


def _timing(o: Orchestrator) -> dict[str, Any]:
    obs = o.obs
    rates = [r for r in obs.safety_rates if r.get("rate_hz") is not None
             and float(r.get("span_s", 0.0)) >= 10.0]
    return {
        "nav_cpu_p50_ms": round(obs.nav_cpu.quantile(0.5) * 1e3, 3),
        "nav_cpu_p99_ms": round(obs.nav_cpu.quantile(0.99) * 1e3, 3),
        "nav_cpu_max_ms": round(obs.nav_cpu.max_s * 1e3, 3),
        "nav_wall_p99_ms": round(obs.nav_wall.quantile(0.99) * 1e3, 3),
        "nav_cycles": obs.nav_cpu.n, "nav_budget_ms": NAV_P99_BUDGET_S * 1e3,
        "safety_cpu_p99_ms": round(obs.safety_cpu.quantile(0.99) * 1e3, 3),
        "safety_cpu_max_ms": round(obs.safety_cpu.max_s * 1e3, 3),
        "safety_wall_p99_ms": round(obs.safety_wall.quantile(0.99) * 1e3, 3),
        "safety_steps": obs.safety_cpu.n, "safety_budget_ms": SAFETY_P99_BUDGET_S * 1e3,
        "safety_rate_min_hz": min((float(r["rate_hz"]) for r in rates), default=None),
        "safety_max_gap_s": max((float(r["max_gap_s"]) for r in rates), default=None),
        "safety_gaps_over": sum(int(r.get("gaps_over", 0)) for r in rates),
    }


def _time(o: Orchestrator) -> dict[str, Any]:
    beat = o.obs.beat or {}
    first = o.obs.first_beat or {}
    wall = wall_perf_counter() - o.started
    building = float(beat.get("wall_s", o.start_wall)) - float(first.get("wall_s", o.start_wall))
    sim = float(beat.get("sim_s", 0.0))
    lapsed = float(beat.get("lapsed_s", 0.0))
    restarts = len(o.obs.restarts)
    return {
        "building_s": round(building, 1), "building_h": round(building / 3600.0, 3),
        "sim_active_s": round(sim, 1), "time_lapse_s": round(lapsed, 1),
        "restart_downtime_s": restarts * 15.0, "wall_s": round(wall, 1),
        "rtf_building": round(building / wall, 2) if wall > 0 else None,
        "rtf_active": round(sim / wall, 2) if wall > 0 else None,
        "rover_cpu_s": round(o.child_cpu_s, 1),
        "rtf_active_per_rover_cpu_s": round(sim / o.child_cpu_s, 2) if o.child_cpu_s else None,
        "rtf_building_target": RTF_TARGET,
    }


def build_report(o: Orchestrator) -> dict[str, Any]:
    """The report of one soak (see the module docstring)."""
    last = o.obs.ends[-1] if o.obs.ends else None
    end = (int(last.get("boot", 0)), float(last.get("sim_s", 0.0))) \
        if last is not None and last.get("t") == "done" else None
    ledger = o.ledger.summary(end)
    faults = _fault_table(o)
    resources = _resources(o)
    timing = _timing(o)
    times = _time(o)
    counts = ledger["counts"]
    results = faults["list"]
    metrics = {
        "collisions": len(o.obs.collisions),
        "collisions_rover_at_fault": sum(1 for c in o.obs.collisions
                                         if c.get("fault") != "person"),
        "collisions_person_at_fault": sum(1 for c in o.obs.collisions
                                          if c.get("fault") == "person"),
        "commands_lost": int(counts.get("lost", 0)),
        "commands_sent": int(counts.get("sent", 0)),
        "commands_answered": int(counts.get("answered", 0)),
        "commands_double_answered": int(counts.get("double_answered", 0)),
        "commands_replayed": int(counts.get("replayed", 0)),
        "faults_planned": len(o.plan),
        "faults_injected": sum(1 for r in results if r.get("outcome") != "not_injected"),
        "faults_recovered": sum(1 for r in results if r.get("outcome") == "recovered"),
        "faults_stopped_safely": sum(1 for r in results
                                     if r.get("outcome") == "stopped_safely"),
        "faults_failed": sum(1 for r in results if r.get("outcome") == "failed"),
        "restarts": len(o.obs.restarts),
        "rss_growth_mb_per_h": resources["rss_growth_mb_per_h"],
        "nav_cpu_p99_ms": timing["nav_cpu_p99_ms"],
        "safety_rate_min_hz": timing["safety_rate_min_hz"],
        "rtf_building": times["rtf_building"],
        "longest_still_driving_s": round(o.obs.still.longest_s, 1),
        "longest_still_driving_at": o.obs.still.longest_at,
    }
    report: dict[str, Any] = {
        "command": "soak", "seed": o.opts.seed, "hours": o.opts.hours,
        "stopped_early": o.stopped_early,
        "clients": o.opts.clients, "visitors": o.opts.visitors, "metrics": metrics,
        "faults": faults, "commands": ledger,
        "restarts": [w.to_json() for w in o.obs.restarts], "files": o.file_checks,
        "resources": resources, "timing": timing, "time": times,
        "load": o.load, "disk": {"method": o.disk.method, "reason": o.disk.reason},
        "notes": o.notes, "failures": o.failures,
        "events": dict(o.obs.kinds), "notable": o.obs.notable[:200],
        "collision_list": o.obs.collisions[:50],
        "clients_detail": [{"client": c.spec.label, "connects": c.connects,
                            "refused_connects": c.refused_connects, "drops": c.drops,
                            "messages_in": c.messages_in,
                            "protocol_errors": c.protocol_errors[:5],
                            "path_edits": c.path.edits if c.path else None,
                            "path_edit_failures": c.path.failures if c.path else None}
                           for c in o.clients],
    }
    checks = checks_of(o, report)
    report["checks"] = checks
    failed = [c["name"] for c in checks if c["ok"] is False]
    report["success"] = not failed
    report["failure"] = ("failed checks: " + ", ".join(failed)) if failed else None
    return report


def format_table(report: dict[str, Any]) -> str:
    """The summary printed at the end: faults per kind, then the checks and the figures."""
    lines = [f"curio soak: seed {report['seed']}, {report['hours']:g} h, {report['clients']} "
             f"clients, {report.get('visitors', 0)} visitors — "
             f"{'PASSED' if report['success'] else 'FAILED'}"]
    stop = report.get("stopped_early")
    if stop:
        lines.append(f"  stopped early ({stop['why']}): the figures cover what ran")
    head = f"{'fault kind':<15}{'plan':>5}{'done':>5}{'rec':>5}{'safe':>5}{'fail':>5}" \
           f"{'health':>7}{'log':>5}{'recover s (median/max)':>24}"
    lines += ["", head, "-" * len(head)]
    for kind, row in report["faults"]["by_kind"].items():
        rec = row["recover_s"]
        ttr = f"{rec['median']:.1f} / {rec['max']:.1f}" if rec.get("n") else "-"
        lines.append(f"{kind:<15}{row['planned']:>5}{row['judged']:>5}{row['recovered']:>5}"
                     f"{row['stopped_safely']:>5}{row['failed'] + row['not_injected']:>5}"
                     f"{row['detected_health']:>7}{row['detected_log']:>5}{ttr:>24}")
    lines.append("")
    for check in report["checks"]:
        mark = {True: "ok  ", False: "FAIL"}.get(check["ok"], "n/a ")
        lines.append(f"  [{mark}] {check['name']}: {check['detail']}")
    t = report["time"]
    lines += ["", f"  building {t['building_h']:.2f} h (time-lapse {t['time_lapse_s']:.0f} s), "
              f"simulated {t['sim_active_s']:.0f} s, wall {t['wall_s']:.0f} s: "
              f"{t['rtf_building']}x building time, {t['rtf_active']}x simulated "
              f"({t['rtf_active_per_rover_cpu_s']}x per rover CPU second)"]
    if report["load"]:
        loads = [row[1] for row in report["load"]]
        lines.append(f"  load average (1 min) {min(loads):.1f}–{max(loads):.1f}, "
                     f"median {statistics.median(loads):.1f}")
    return "\n".join(lines)
