"""``curio fleet sim --processes``: the fleet in its deployment shape, on real time.

Each rover is a separate ``curio run`` process (the simulator on the real clock, its own data
directory, ``fleet.mode = "client"`` connected to this process's Zenoh router on a free
loopback port, ``fleet.share_sim_truth`` so that every process puts the other rovers into its
own world); this process runs the fleet manager on that router. The scenario's tours (the
fleet ``tour-day``'s by default) are created on the manager and each is asked for once as soon
as every rover is online; the run ends when they are all done or dropped, or after
``--duration`` seconds (default 900). The report: the jobs, the rovers as the manager saw
them last, and where each rover's log is.

A time-lapsed day cannot be run this way (every process has its own real clock), and the
simulated worlds are coupled at the rovers' pose rate (5 Hz) rather than every physics step.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import secrets
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from curio.core.clock import RealClock, wall_perf_counter
from curio.core.config import Config
from curio.core.fileio import atomic_write_json
from curio.fleet.auth import FleetKeyring, KeyEntry
from curio.fleet.manager.service import FleetManager
from curio.fleet.zenoh_link import ZenohSettings, ZenohTransport, free_local_endpoint, load_zenoh
from curio.scenarios.fleet.base import FleetScenario
from curio.tours.model import stop_from_json

__all__ = ["run_processes"]

DEFAULT_DURATION_S = 900.0


def _rover_args(config: Path | None, overrides: list[str], name: str, endpoint: str,
                home: tuple[float, float, float], data: Path, seed: int) -> list[str]:
    pose = f"[{home[0]}, {home[1]}, {home[2]}]"
    home_path = (f'[{{name = "Home", points = [[{home[0]}, {home[1]}]], '
                 f'yaw_deg = [{math.degrees(home[2])}]}}]')
    sets = ["fleet.enabled=true", f"fleet.rover={name}", "fleet.mode=client",
            f'fleet.connect=["{endpoint}"]', "fleet.share_sim_truth=true",
            f"robot.name={name}", f"robot.home={pose}", f"sim.start={pose}", f"sim.seed={seed}",
            'bt.tree="tour"', "bt.speak=false", f"bt.paths={home_path}", "web.enabled=false",
            "record.enabled=false",
            f'data_dir="{data}"', *overrides]
    args = [sys.executable, "-m", "curio", "run"]
    if config is not None:
        args += ["--config", str(config)]
    for item in sets:
        args += ["--set", item]
    return args


def run_processes(cfg: Config, scenario: FleetScenario, args: argparse.Namespace) -> int:
    """Run ``scenario``'s tours with separate rover processes (see the module docstring)."""
    load_zenoh()
    n = args.rovers or scenario.default_rovers
    homes = scenario.starts(n, args.seed)
    root = cfg.resolve(cfg.data_dir) / "fleet" / f"processes-seed{args.seed}"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    endpoint = free_local_endpoint()
    key = KeyEntry("fleet", "operator", secrets.token_urlsafe(24))
    procs: list[tuple[str, subprocess.Popen[bytes], Path]] = []
    for i in range(n):
        name = f"r{i + 1}"
        data = root / name
        data.mkdir()
        FleetKeyring(data / cfg.fleet.keys_file).add(key.name, key.role, key.secret)
        log_path = root / f"{name}.log"
        with open(log_path, "wb") as log_file:
            procs.append((name, subprocess.Popen(
                _rover_args(args.config, args.overrides, name, endpoint, homes[i], data,
                            args.seed * 100 + i), stdout=log_file, stderr=subprocess.STDOUT),
                log_path))
    mcfg = cfg.model_copy(update={"data_dir": str(root / "manager")})
    try:
        report = asyncio.run(_manage(mcfg, endpoint, key, [p[0] for p in procs], scenario,
                                     args.duration or DEFAULT_DURATION_S))
    finally:
        for _, proc, _ in procs:
            proc.terminate()
        for _, proc, _ in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
    report["logs"] = {name: str(path) for name, _, path in procs}
    report["exit_codes"] = {name: proc.returncode for name, proc, _ in procs}
    if args.report is not None:
        atomic_write_json(args.report, report)
    print(json.dumps({k: report[k] for k in ("scenario", "rovers", "success", "jobs_by_state",
                                             "wall_time_s")}, indent=1))
    return 0 if report["success"] else 1


async def _manage(cfg: Config, endpoint: str, key: KeyEntry, names: list[str],
                  scenario: FleetScenario, duration_s: float) -> dict[str, Any]:
    clock = RealClock()
    transport = ZenohTransport("manager", ZenohSettings("router", listen=(endpoint,)),
                               threaded_puts=True)
    manager = FleetManager(cfg, clock, transport, key, expected=names)
    ids = [manager.tours.create(name, [stop_from_json(s) for s in stops]).id
           for name, stops in scenario.tours().items()]
    start = wall_perf_counter()
    await manager.start()
    online = await clock.wait_until(lambda: all(
        r["online"] and r["ready"] for r in manager.rovers_json()), 120.0, 0.5)
    if online:
        for tour_id in ids:
            manager.dispatch_tour(tour_id, "processes")
    await clock.wait_until(lambda: bool(manager.dispatcher.jobs) and not
                           manager.dispatcher.active(), duration_s, 1.0)
    summary = manager.summary()
    rovers = manager.rovers_json()
    jobs = [j.to_json() for j in manager.dispatcher.jobs]
    await manager.stop()
    transport.close()
    return {"scenario": f"{scenario.name} (processes)", "rovers": len(names),
            "success": online and summary["by_state"].get("done", 0) == len(ids) > 0,
            "all_online": online, "jobs_by_state": summary["by_state"], "jobs": jobs,
            "redispatches": summary["redispatches"],
            "rovers_seen": [{k: r[k] for k in ("name", "online", "state", "battery_v")}
                            for r in rovers],
            "wall_time_s": round(wall_perf_counter() - start, 1)}
