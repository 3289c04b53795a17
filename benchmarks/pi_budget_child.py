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
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
from typing import Any

from curio import kernels
from curio.app import App
from curio.core.bus import Topic
from curio.core.clock import SimClock, process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.core.topics import CMD_VEL, CMD_VEL_NAV
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

SETTLE_S = 3.0


def main(out_path: str, duration_s: float, seed: int) -> None:
    """Run the tour for ``duration_s`` of real time; write the measurements."""
    lateness: dict[str, list[float]] = {"control": [], "safety": []}
    anchor: dict[str, float] = {}
    original_run = SimClock.run

    async def anchored_run(self: SimClock, *args: Any, **kwargs: Any) -> None:
        anchor["wall"], anchor["sim"] = wall_perf_counter(), self.now()
        await original_run(self, *args, **kwargs)

    SimClock.run = anchored_run  # type: ignore[method-assign]

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
                   "sim_time_s": report["sim_time_s"], "success": report["success"],
                   "control_hz": cfg.nav.controller.rate_hz, "safety_hz": cfg.nav.safety.rate_hz},
                  fh)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), int(sys.argv[3]))
