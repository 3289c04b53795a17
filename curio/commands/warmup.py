"""``curio warmup``: compile every numba kernel into the cache before the rover needs it.

    curio warmup [--config PATH] [--set KEY=VALUE]...

Run it once after installing or updating Curio, as the user that runs the rover (``sudo -u
curio``), so the cache in ``numba_cache_dir`` is written by that user; ``curio check`` then
reports the cache warm. It drives the simulator for a minute of simulated time in this process
(:func:`curio.kernels.warm`), which compiles each kernel for the argument types the application
uses. Exit code 0 when every kernel ended up compiled, 1 when the workload missed one.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import tempfile
from pathlib import Path
from typing import Any, TextIO

from curio import kernels
from curio.commands.common import run_command
from curio.core.clock import process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, Config, load_config

__all__ = ["config_args", "main", "prepare", "run_warmup", "warm"]

log = logging.getLogger("curio.kernels")


def _workload_config(cfg: Config, data_dir: Path, mode: str, visitors: int) -> Config:
    """``cfg`` turned into a headless simulated run (whatever its drivers mode; no dashboard,
    no recording, no speech) that keeps its own data in ``data_dir``; ``mode`` is
    ``localization.mode``; ``visitors`` walk the simulated building (the crowd's kernels, the
    people tracker's)."""
    run = cfg.model_copy(deep=True)
    run.data_dir = str(data_dir)
    run.drivers.mode = "sim"
    run.web.enabled = False
    run.record.enabled = False
    run.bt.speak = False
    run.localization.mode = mode  # type: ignore[assignment]
    run.sim.crowd.visitors = visitors
    if not run.bt.tour_stops:
        # A rover whose tours are authored on the dashboard has no configured stops, and the
        # guided tour needs some: the workload drives the shipped building and its tour (the
        # kernels' argument types do not depend on the building). Before, the warmup failed
        # on such a rover and every kernel compiled inside the running loop.
        shipped = load_config(REPO_ROOT / "config.toml")
        run.bt.tour_stops = shipped.bt.tour_stops
        run.sim.world = str(shipped.resolve(shipped.sim.world))
        run.localization.map_yaml = None  # the world's map
        run.sim.start = None
        run.robot.home = shipped.robot.home
    return run


def _warm_helpers() -> None:
    """The kernels a short drive may not reach, called as the application calls them (the
    same array layouts: numba compiles one version per layout, and a version missing from the
    cache would compile inside the running loop)."""
    import numpy as np

    from curio.people.stage_kernel import path_clearances, people_clearances
    from curio.safety.stop_zone import polygon_distances

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    polygon_distances(np.array([[0.5, 0.5], [2.0, 0.0]]), square)
    # The people stage (curio/people/stage.py): now, over the horizon, and other rovers'
    # known futures (fleet.traffic.predict_peers) — always with C-contiguous arrays.
    footprint = square - 0.5
    people = np.zeros((2, 4))
    people[:, 0] = (1.0, 2.0)
    times = np.linspace(0.0, 4.0, 11)
    people_clearances(np.array([[[0.0, 0.0, 0.0]]]), times[:1], people, footprint, 0.25,
                      np.empty((1, 1, 2)))
    steps = np.zeros((3, 11, 3))
    people_clearances(steps, times, people, footprint, 0.25, np.empty((3, 11, 2)))
    futures = np.ones((1, 11, 2))
    path_clearances(steps, futures, footprint, np.full(1, 0.25), np.empty((3, 11, 1)))


async def _drive(cfg: Config, scenario: str, sim_s: float) -> None:
    from curio.scenarios import get_scenario
    from curio.scenarios.base import ScenarioArgs, run_scenario

    await run_scenario(get_scenario(scenario), cfg, ScenarioArgs(duration_s=sim_s))


def warm(cfg: Config, sim_s: float = 30.0) -> dict[str, Any]:
    """Compile every kernel into the cache by running the application on simulated time in
    this process: ``sim_s`` of the guided tour among a few visitors (localisation, costmap,
    planner, controller, obstacles, safety, people, simulator and its crowd) and of the square
    drive while mapping (scan matching, the map). Return ``{"seconds", "cpu_s", "compiled",
    "cold"}``: wall and CPU time, the kernels the cache holds afterwards, and those it still
    lacks (a workload that misses them)."""
    kernels.use_cache_dir(cfg)
    t0, c0 = wall_perf_counter(), process_cpu_time()
    with tempfile.TemporaryDirectory(prefix="curio-warmup-") as tmp:
        for scenario, mode, visitors in (("guided-tour", "localize", 8), ("square", "map", 0)):
            run_cfg = _workload_config(cfg, Path(tmp) / scenario, mode, visitors)
            asyncio.run(_drive(run_cfg, scenario, sim_s))
    _warm_helpers()
    found = kernels.status()  # what the cache holds now (a kernel loaded from it, or only
    # compiled inside its callers, has no signature of its own in memory)
    compiled = [k.name for k in found if k.cached]
    cold = [k.name for k in found if not k.cached]
    return {"seconds": wall_perf_counter() - t0, "cpu_s": process_cpu_time() - c0,
            "compiled": compiled, "cold": cold}


def config_args(config: Path | str | None, overrides: list[str]) -> list[str]:
    """The ``--config``/``--set`` arguments that give a child ``curio`` the same config."""
    return [*(["--config", str(config)] if config else []), *(f"--set={o}" for o in overrides)]


def run_warmup(args: list[str]) -> int:
    """``curio warmup ARGS`` in a child process, its output thrown away (its simulated drive's
    log is not the caller's); its exit code."""
    import subprocess

    return subprocess.run([sys.executable, "-m", "curio", "warmup", *args], check=False,
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode


def prepare(cfg: Config, config_args: list[str]) -> None:
    """Before the rover starts: use the configured cache and load every cached kernel; when
    some kernel has nothing cached (a first start, or new sources), compile them all first by
    running ``curio warmup`` with ``config_args`` (``--config``/``--set``) in a child process
    (the workload's memory is not kept by the rover's process), then load them. A kernel
    compiling inside the running loop would stall it for seconds (longer than the systemd
    watchdog allows on a Pi)."""
    where = kernels.describe(kernels.use_cache_dir(cfg))
    t0 = wall_perf_counter()
    loaded, cold = kernels.preload()
    kernels.watch_compiles()
    if not cold:
        log.info("compiled kernels: %d loaded from the cache (%s) in %.1f s", loaded, where,
                 wall_perf_counter() - t0)
        return
    log.warning("compiled kernels: %d of %d not in the cache (%s): compiling them before the "
                "rover starts; 'curio warmup' after installing or updating Curio avoids this",
                len(cold), len(kernels.dispatchers()), where)
    # The child's own output (its simulated drive's log) is not the rover's: only what is
    # still missing afterwards is said (a warmup that failed, e.g. on a map the rover cannot
    # load either: the rover's own start then says what is wrong).
    code = run_warmup(config_args)
    more, cold = kernels.preload()
    if cold and code != 2:  # 2: a setup error the rover's start will name
        log.warning("compiled kernels: still not cached after the warmup (they compile at "
                    "their first call): %s", ", ".join(cold))
    else:
        log.debug("compiled kernels: %d loaded after the warmup in %.1f s", loaded + more,
                  wall_perf_counter() - t0)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="curio warmup", description=(
        "Compile every numba kernel into the cache (numba_cache_dir) so the first start after "
        "an install or an update does not compile."))
    ap.add_argument("--config", help="config file (default: ./config.toml or the shipped one)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override one config key (repeatable)")
    return ap


def _body(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    cfg = load_config(args.config, args.overrides)
    where = kernels.use_cache_dir(cfg)
    result = warm(cfg)
    total = len(result["compiled"]) + len(result["cold"])
    out.write(f"compiled kernels: {len(result['compiled'])} of {total} in the cache "
              f"({kernels.describe(where)}), {result['seconds']:.1f} s "
              f"({result['cpu_s']:.1f} s CPU)\n")
    if result["cold"]:
        err.write("curio warmup: not compiled by the workload (they compile at their first "
                  f"call): {', '.join(result['cold'])}\n")
        return 1
    return 0


def main(argv: list[str] | None = None, out: TextIO | None = None,
         err: TextIO | None = None) -> int:
    """Run ``curio warmup``; return the exit code."""
    return run_command("warmup", _parser(), argv, out or sys.stdout, err or sys.stderr, _body)
