"""The process ``curio bench pi-budget`` runs under a CPU quota: the guided tour at real time.

    python -m benchmarks.pi_budget_child OUT.json DURATION_S SEED

The whole application (simulator, dashboard hub, everything ``curio run`` starts) runs the
``guided-tour`` scenario on a simulated clock paced at real time (``speed=1``). Every tick of
the navigator's control loop (``/cmd_vel_nav``) and of the safety stage (``/cmd_vel``) is
stamped with the simulated time it was due; a bus tap notes the wall time it was published, so
``lateness = wall − (wall at the start + simulated time since the start)`` is how late the tick
came against a real-time schedule — what the rover would see. As ``curio run`` does, every
cached kernel is loaded before the start, and the first ``SETTLE_S`` seconds (the first scans,
the planner's first use) are left out. Writes the ticks' lateness, the process's CPU and the
simulated/wall time to ``OUT.json``.

It also profiles what a stall is made of: every event-loop callback that held the loop for
more than ``SLOW_CALLBACK_S`` of wall time (its task's name, wall and CPU time: CPU × the
slowdown ≈ wall is a burst of work the quota stretched; wall ≫ CPU is the process waiting —
throttled, preempted or blocked in a system call) and every collection of the cyclic garbage
collector's older generations (wall and CPU time, the number of objects it had to walk).

Work the application hands to ``clock.offload`` runs in a worker thread, as on the rover's real
clock (the simulated clock runs it inline, for determinism): the global planner's searches and
the event log's commits do not hold the loop here either.
"""

from __future__ import annotations

import asyncio
import gc
import json
import sys
import tempfile
from typing import Any

from curio import kernels
from curio.app import App
from curio.core.bus import Topic
from curio.core.clock import (
    RealClock,
    SimClock,
    process_cpu_time,
    thread_cpu_time,
    wall_perf_counter,
)
from curio.core.config import REPO_ROOT, load_config
from curio.core.topics import CMD_VEL, CMD_VEL_NAV
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

SETTLE_S = 3.0
SLOW_CALLBACK_S = 0.02  # a callback holding the loop longer than this is recorded


def _profile_stalls(anchor: dict[str, float]) -> tuple[list[dict[str, Any]],
                                                       list[dict[str, Any]]]:
    """Record slow event-loop callbacks and older-generation collections (module docstring);
    ``at_s`` is wall seconds since the tour's clock started."""
    slow: list[dict[str, Any]] = []
    collections: list[dict[str, Any]] = []
    run_handle = asyncio.Handle._run

    def timed_run(handle: asyncio.Handle) -> None:
        w0, c0 = wall_perf_counter(), thread_cpu_time()
        run_handle(handle)
        wall = wall_perf_counter() - w0
        if wall > SLOW_CALLBACK_S and "wall" in anchor:
            owner = getattr(handle._callback, "__self__", None)  # type: ignore[attr-defined]
            name = (owner.get_name() if isinstance(owner, asyncio.Task)
                    else getattr(handle._callback, "__qualname__", "?"))  # type: ignore[attr-defined]
            slow.append({"at_s": round(w0 - anchor["wall"], 3), "name": name,
                         "wall_ms": round(1e3 * wall, 2),
                         "cpu_ms": round(1e3 * (thread_cpu_time() - c0), 2)})

    asyncio.Handle._run = timed_run  # type: ignore[method-assign]
    started: dict[str, float] = {}

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if info["generation"] < 1:
            return
        if phase == "start":
            started["objects"] = float(sum(len(gc.get_objects(g))
                                           for g in range(info["generation"] + 1)))
            started["wall"], started["cpu"] = wall_perf_counter(), thread_cpu_time()
            return
        if "wall" in anchor and "wall" in started:
            collections.append({
                "at_s": round(started["wall"] - anchor["wall"], 3),
                "generation": info["generation"],
                "wall_ms": round(1e3 * (wall_perf_counter() - started["wall"]), 2),
                "cpu_ms": round(1e3 * (thread_cpu_time() - started["cpu"]), 2),
                "objects_walked": int(started["objects"]),
                "frozen_objects": gc.get_freeze_count()})

    gc.callbacks.append(on_gc)
    return slow, collections


def main(out_path: str, duration_s: float, seed: int) -> None:
    """Run the tour for ``duration_s`` of real time; write the measurements."""
    lateness: dict[str, list[float]] = {"control": [], "safety": []}
    anchor: dict[str, float] = {}
    original_run = SimClock.run

    async def anchored_run(self: SimClock, *args: Any, **kwargs: Any) -> None:
        anchor["wall"], anchor["sim"] = wall_perf_counter(), self.now()
        await original_run(self, *args, **kwargs)

    SimClock.run = anchored_run  # type: ignore[method-assign]
    # As on the rover's RealClock, work handed to ``clock.offload`` (the global planner, the
    # event log's SQLite commits) runs in a worker thread while the loop goes on; the simulated
    # clock runs it inline to stay deterministic, which would put every plan on the loop.
    SimClock.offload = RealClock.offload  # type: ignore[method-assign]
    slow_callbacks, collections = _profile_stalls(anchor)

    def tap(topic: Topic[Any], msg: Any) -> None:
        if "wall" not in anchor or msg.stamp < anchor["sim"] + SETTLE_S:
            return
        if topic is CMD_VEL_NAV:
            key = "control"
        elif topic is CMD_VEL and getattr(msg, "source", "").startswith("safety"):
            key = "safety"
        else:
            return
        due = anchor["wall"] + (msg.stamp - anchor["sim"])
        lateness[key].append(wall_perf_counter() - due)

    async def started(app: App) -> None:
        app.bus.add_tap(tap)

    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(REPO_ROOT / "config.toml",
                          [f'data_dir="{tmp}"', "web.port=0", "bt.speak=false"])
        args = ScenarioArgs(seed=seed, speed=1.0, duration_s=duration_s, web=True)
        kernels.preload()
        c0, w0 = process_cpu_time(), wall_perf_counter()
        report = asyncio.run(run_scenario(get_scenario("guided-tour"), cfg, args,
                                          on_app=started))
        cpu, wall = process_cpu_time() - c0, wall_perf_counter() - w0
    with open(out_path, "w", encoding="utf-8") as fh:
        json.dump({"lateness_s": lateness, "cpu_s": cpu, "wall_s": wall,
                   "slow_callbacks": slow_callbacks, "collections": collections,
                   "sim_time_s": report["sim_time_s"], "success": report["success"],
                   "control_hz": cfg.nav.controller.rate_hz, "safety_hz": cfg.nav.safety.rate_hz},
                  fh)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), int(sys.argv[3]))
