"""A Raspberry Pi 4's CPU budget: does the stack keep its control and safety rates on one core
slowed to a Pi's speed? (``curio bench pi-budget``)

The whole application (``benchmarks/pi_budget_child.py``: the guided tour with the simulator and
the dashboard hub, on a simulated clock paced at real time) runs in a child process pinned to
one core, once with the core to itself and once with a CPU quota of ``1 / slowdown`` of it —
a Pi 4 core is ~3–5× slower than the development machines (``slowdown=4`` by default; with
``pi_calibration=N``, the naive ray caster's scans per CPU second measured on a Pi with
``benchmarks/calibration.py``, the factor is this host's calibration divided by N). The quota
is a CFS bandwidth limit of ``period × 1/slowdown`` per 10 ms period: a cgroup (v2
``cpu.max`` or v1 ``cpu.cfs_quota_us``) when this process may create one (root, or a delegated
cgroup), else a stop/continue duty cycle sent from this process (the same limit, coarser).
The simulator's own CPU (~20 % of the stack's) runs inside the quota too: the test is
pessimistic by that much.

Per row, for the navigator's control loop (``nav.controller.rate_hz``, its ``/cmd_vel_nav``
ticks while a goal is active) and the safety stage (``safety.rate_hz``, ``/cmd_vel``): the
lateness of each tick against the real-time schedule (p50 / p99 / max, ms) and the share of
ticks more than one period late (``*_missed_pct``); ``keeps_rates`` when no safety tick and at
most 1 % of control ticks miss their period and the p99 lateness of both stays under half a
period. ``cpu_pct_of_quota``: how much of its budget the process used.

And what the stalls were made of (``benchmarks/pi_budget_child.py`` profiles them):
``slowest_callbacks`` (the event-loop callbacks that held the loop longest, wall against CPU
time: CPU × slowdown ≈ wall is a burst the quota stretched, wall ≫ CPU a wait), the full
(generation-2) garbage collections and their longest pause, and the cgroup's
``throttled_periods`` / ``throttled_ms``.

Options (``--set``): ``duration=120`` (real seconds per row), ``slowdown=4``,
``pi_calibration=`` (scans per CPU second on a Pi), ``unthrottled=1`` (also the row without a
quota).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from benchmarks.calibration import naive_scans_per_cpu_s
from curio.commands.bench import BenchOptions
from curio.core.clock import wall_sleep
from curio.core.config import REPO_ROOT

PERIOD_US = 10_000


def _cgroup_quota(pid: int, fraction: float) -> tuple[str, Path] | None:
    """Put ``pid`` into a new cgroup limited to ``fraction`` of a CPU; (method, dir) or None."""
    quota = max(1000, int(PERIOD_US * fraction))
    name = f"curio-pi-budget-{os.getpid()}"
    v2 = Path("/sys/fs/cgroup")
    v1 = v2 / "cpu"
    try:
        if (v2 / "cgroup.controllers").exists():
            d = v2 / name
            d.mkdir()
            (d / "cpu.max").write_text(f"{quota} {PERIOD_US}")
            (d / "cgroup.procs").write_text(str(pid))
            return "cgroup v2 cpu.max", d
        if (v1 / "cpu.cfs_quota_us").exists():
            d = v1 / name
            d.mkdir()
            (d / "cpu.cfs_period_us").write_text(str(PERIOD_US))
            (d / "cpu.cfs_quota_us").write_text(str(quota))
            (d / "cgroup.procs").write_text(str(pid))
            return "cgroup v1 cpu.cfs_quota_us", d
    except OSError:
        return None
    return None


@contextlib.contextmanager
def _duty_cycle(pid: int, fraction: float) -> Iterator[None]:
    """SIGSTOP/SIGCONT ``pid`` so it runs ``fraction`` of each 10 ms period (no cgroup)."""
    done = threading.Event()
    on_s, off_s = PERIOD_US * fraction / 1e6, PERIOD_US * (1 - fraction) / 1e6

    def cycle() -> None:
        while not done.is_set():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
            wall_sleep(on_s)
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGSTOP)
            wall_sleep(off_s)
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)

    thread = threading.Thread(target=cycle, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def _run_child(duration_s: float, seed: int, core: int,
               fraction: float | None) -> tuple[dict[str, Any], str]:
    """The tour in a child process on ``core`` with ``fraction`` of it (None: all of it)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]))
        proc = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.pi_budget_child", str(out), str(duration_s),
             str(seed)], cwd=REPO_ROOT, env=env, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        os.sched_setaffinity(proc.pid, {core})
        method, cgroup = "none", None
        guard: contextlib.AbstractContextManager[None] = contextlib.nullcontext()
        if fraction is not None:
            got = _cgroup_quota(proc.pid, fraction)
            if got is not None:
                method, cgroup = got
            else:
                method, guard = "SIGSTOP/SIGCONT duty cycle", _duty_cycle(proc.pid, fraction)
        throttling: dict[str, int] = {}
        try:
            with guard:
                proc.wait()
            if cgroup is not None:
                with contextlib.suppress(OSError):
                    for line in (cgroup / "cpu.stat").read_text().splitlines():
                        key, _, value = line.partition(" ")
                        throttling[key] = int(value)
        finally:
            if cgroup is not None:
                with contextlib.suppress(OSError):
                    cgroup.rmdir()
        if proc.returncode != 0 or not out.exists():
            raise RuntimeError(f"the pi-budget child failed (exit {proc.returncode})")
        result: dict[str, Any] = json.loads(out.read_text(encoding="utf-8"))
        result["throttling"] = throttling
        return result, method


def _loop_figures(name: str, lateness_s: list[float], rate_hz: float) -> dict[str, Any]:
    period = 1.0 / rate_hz
    if not lateness_s:
        return {f"{name}_ticks": 0}
    ms = sorted(1e3 * v for v in lateness_s)
    p99 = ms[min(len(ms) - 1, int(0.99 * len(ms)))]
    missed = sum(1 for v in lateness_s if v > period)
    return {
        f"{name}_hz": rate_hz,
        f"{name}_ticks": len(ms),
        f"{name}_late_p50_ms": round(statistics.median(ms), 2),
        f"{name}_late_p99_ms": round(p99, 2),
        f"{name}_late_max_ms": round(ms[-1], 2),
        f"{name}_missed_pct": round(100.0 * missed / len(ms), 3),
    }


def _stall_profile(result: dict[str, Any]) -> dict[str, Any]:
    """What held the loop (the child's profile): the slowest callbacks with their CPU, the
    older-generation garbage collections, and the cgroup's throttling counters."""
    slow = sorted(result.get("slow_callbacks", []), key=lambda c: -c["wall_ms"])
    gcs = result.get("collections", [])
    full = [c for c in gcs if c["generation"] == 2]
    thr = result.get("throttling", {})
    throttled_ms = thr.get("throttled_usec", thr.get("throttled_time", 0) // 1000) / 1e3
    return {
        "slow_callbacks": len(slow),
        "slowest_callbacks": ", ".join(
            f"{c['name']} {c['wall_ms']:.0f} ms wall / {c['cpu_ms']:.1f} ms CPU at "
            f"{c['at_s']:.0f} s" for c in slow[:5]),
        "full_collections": len(full),
        "full_collection_max_ms": max((c["wall_ms"] for c in full), default=0.0),
        "full_collection_cpu_max_ms": max((c["cpu_ms"] for c in full), default=0.0),
        "throttled_periods": thr.get("nr_throttled", 0),
        "throttled_ms": round(throttled_ms, 1),
    }


def _row(subject: str, result: dict[str, Any], method: str, fraction: float | None
         ) -> dict[str, Any]:
    lat = result["lateness_s"]
    row: dict[str, Any] = {
        "subject": subject,
        "quota_pct_core": round(100 * fraction, 1) if fraction is not None else 100.0,
        "quota_method": method,
        "wall_s": round(result["wall_s"], 1),
        "sim_time_s": result["sim_time_s"],
        "cpu_pct_of_quota": round(100 * result["cpu_s"] / result["wall_s"] / (fraction or 1.0),
                                  2),
        **_loop_figures("control", lat["control"], result["control_hz"]),
        **_loop_figures("safety", lat["safety"], result["safety_hz"]),
    }
    row.update(_stall_profile(result))
    control_period_ms = 1e3 / result["control_hz"]
    safety_period_ms = 1e3 / result["safety_hz"]
    row["keeps_rates"] = bool(
        row.get("safety_ticks", 0) > 0 and row.get("control_ticks", 0) > 0
        and row["safety_missed_pct"] == 0.0 and row["control_missed_pct"] <= 1.0
        and row["safety_late_p99_ms"] < safety_period_ms / 2
        and row["control_late_p99_ms"] < control_period_ms / 2)
    return row


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """The tour on one core without and with the Pi-sized quota; one row each."""
    duration = float(opts.extra.get("duration", 120.0))
    calib = naive_scans_per_cpu_s()
    pi_cal = opts.extra.get("pi_calibration")
    slowdown = calib / float(pi_cal) if pi_cal else float(opts.extra.get("slowdown", 4.0))
    core = sorted(os.sched_getaffinity(0))[-1]
    rows = []
    if str(opts.extra.get("unthrottled", "1")) not in ("0", "false", ""):
        result, method = _run_child(duration, opts.seed, core, None)
        rows.append(_row("one core, no quota", result, method, None))
    fraction = 1.0 / slowdown
    result, method = _run_child(duration, opts.seed, core, fraction)
    rows.append(_row(f"Pi 4 budget (1/{slowdown:.2g} core)", result, method, fraction))
    for row in rows:
        row["slowdown"] = round(slowdown, 2)
        row["naive_scans_per_cpu_s"] = round(calib, 3)
        row["load_avg_1m"] = round(os.getloadavg()[0], 2)
    return rows
