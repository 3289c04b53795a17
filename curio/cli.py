"""The ``curio`` command.

``curio run``, ``curio sim SCENARIO``, ``curio config show``, ``curio check``,
``curio emulate DEVICE``, ``curio map ...``, ``curio report --day YYYY-MM-DD``,
``curio replay FILE``, ``curio export ...``, ``curio token ...``, ``curio fleet ...``,
``curio soak``, ``curio warmup`` and
``curio bench NAME``. Exit codes: 0 success,
1 failure (a scenario or a check failed), 2 bad arguments, bad configuration or a setup the user
can fix (a missing or corrupt file, a busy port): one line on stderr, no traceback.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import sys
from pathlib import Path
from typing import Any

from curio.core.config import Config, ConfigError, dump_config, load_config
from curio.core.errors import SetupError

__all__ = ["main"]

log = logging.getLogger("curio")


class UsageError(Exception):
    """Bad command-line arguments (exit code 2)."""


def _floats(text: str, counts: tuple[int, ...], what: str) -> tuple[float, ...]:
    parts = [p.strip() for p in text.split(",")]
    if len(parts) not in counts:
        allowed = " or ".join(str(c) for c in counts)
        raise UsageError(f"{what} takes {allowed} comma-separated numbers, got '{text}'")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise UsageError(f"{what} takes numbers like 1.5,-2,0.3, got '{text}'") from None
    if not all(math.isfinite(v) for v in values):
        raise UsageError(f"{what} must be finite numbers, got '{text}'")
    return values


DESCRIPTION = ("Curio: the autonomous tour-guide rover in one process. 'curio run' drives "
               "the rover (the shipped config runs the simulator with the dashboard); 'curio "
               "sim' runs a scripted scenario on simulated time.")
CONFIG_HELP = ("config TOML (default: ./config.toml if there is one, else the config.toml "
               "shipped with Curio)")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("curio")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown (not installed)"


def _add_config_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help=CONFIG_HELP)
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="override one config key (repeatable)")


def _build_parser() -> argparse.ArgumentParser:
    from curio.commands.bench import available_benchmarks
    from curio.scenarios import SCENARIOS

    parser = argparse.ArgumentParser(prog="curio", description=DESCRIPTION)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--version", action="version", version=f"curio {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser("run", help="run the robot (the shipped config runs the simulator)")
    _add_config_args(run)

    sim = sub.add_parser("sim", help="run a scripted scenario headless on simulated time")
    sim.add_argument("scenario", help="one of: " + ", ".join(sorted(SCENARIOS)))
    sim.add_argument("--map", dest="map_yaml", help="world map YAML (default: sim.world)")
    sim.add_argument("--start", help="start pose X,Y,YAW in map (m, m, rad)")
    sim.add_argument("--goal", help="goal X,Y[,YAW] in map (m, m, rad)")
    sim.add_argument("--seed", type=int, help="random seed >= 0 (default: sim.seed)")
    sim.add_argument("--visitors", type=int,
                     help="simulated visitors walking the world, 0..100 (default: "
                          "sim.crowd.visitors; the crowd scenario: 10)")
    sim.add_argument("--speed", default=None,
                     help="N x real time, or max (default: max; 1 with --web)")
    sim.add_argument("--duration", type=float, help="time limit, simulated seconds")
    sim.add_argument("--report", type=Path, help="write the JSON report here")
    sim.add_argument("--web", action="store_true", help="serve the dashboard (real time)")
    sim.add_argument("--record", type=Path, metavar="FILE.mcap",
                     help="record the run (every topic) to this MCAP file")
    _add_config_args(sim)

    config = sub.add_parser("config", help="configuration tools")
    config_sub = config.add_subparsers(dest="config_command", required=True, metavar="ACTION")
    show = config_sub.add_parser("show", help="print the effective configuration")
    _add_config_args(show)

    for name, helptext in (
        ("check", "diagnose the hardware and say how to fix what is wrong"),
        ("emulate", "serve a device emulator (arduino, rplidar) on a pseudo-terminal"),
        ("map", "build, save and inspect maps"),
        ("replay", "replay a recording (or a ROS bag) through estimation and navigation and "
                   "report where it diverges"),
        ("export", "convert a recording: --ros2 writes a ROS 2 bag (ros2 bag play)"),
        ("token", "create, list, revoke and rotate the dashboard's named tokens"),
        ("pose", "relocalise a running rover or set its pose on the map"),
        ("zones", "list a map's keep-out and speed zones, export them as Nav2 masks"),
        ("fleet", "fleet manager, fleet simulator, keys, signed commands (curio[fleet])"),
        ("warmup", "compile every numba kernel into the cache (numba_cache_dir) before the "
                   "first start"),
    ):
        p = sub.add_parser(name, help=helptext, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)

    report = sub.add_parser("report", help="the daily report from the event log")
    from curio.commands.report import add_arguments as report_arguments

    report_arguments(report)
    _add_config_args(report)

    soak = sub.add_parser("soak", help="days without a person: the whole rover with operators, "
                                       "a fault campaign and kill -9; what was lost")
    from curio.commands.soak import add_arguments as soak_arguments

    soak_arguments(soak)
    _add_config_args(soak)

    bench = sub.add_parser("bench", help="run a benchmark and print its table")
    bench.add_argument("name", help="one of: " + ", ".join(available_benchmarks()))
    bench.add_argument("--json", type=Path, help="write the result JSON here")
    bench.add_argument("--map", dest="map_yaml", help="map YAML for map-based benchmarks")
    bench.add_argument("--pairs", type=int, help="number of start/goal pairs or runs")
    bench.add_argument("--seed", type=int, default=1, help="random seed >= 0")
    bench.add_argument("--set", dest="extra", action="append", default=[], metavar="KEY=VALUE",
                       help="benchmark-specific option (repeatable)")
    return parser


def _load(args: argparse.Namespace) -> Config:
    return load_config(args.config, args.overrides)


def _cmd_config(args: argparse.Namespace) -> int:
    print(dump_config(_load(args)), end="")
    return 0


def _cmd_sim(args: argparse.Namespace) -> int:
    from curio.scenarios import get_scenario
    from curio.scenarios.base import ScenarioArgs, run_scenario

    try:
        scenario = get_scenario(args.scenario)
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from None
    if args.speed is None:
        speed = 1.0 if args.web else None
    elif args.speed == "max":
        speed = None
    else:
        try:
            speed = float(args.speed)
        except ValueError:
            raise UsageError(f"--speed takes a number > 0 or 'max', got '{args.speed}'") from None
        if not speed > 0:
            raise UsageError(f"--speed takes a number > 0 or 'max', got '{args.speed}'")
    start_values = _floats(args.start, (3,), "--start") if args.start else None
    start = None if start_values is None else (start_values[0], start_values[1], start_values[2])
    goal_values = _floats(args.goal, (2, 3), "--goal") if args.goal else None
    goal = None
    if goal_values is not None:
        goal = (goal_values[0], goal_values[1], goal_values[2] if len(goal_values) == 3 else None)
    if args.seed is not None and args.seed < 0:
        raise UsageError(f"--seed takes a whole number >= 0, got {args.seed}")
    if args.visitors is not None and not 0 <= args.visitors <= 100:
        raise UsageError(f"--visitors takes a whole number 0..100, got {args.visitors}")
    if args.duration is not None and not args.duration > 0:
        raise UsageError(f"--duration takes simulated seconds > 0, got {args.duration}")
    if args.map_yaml is not None and not Path(args.map_yaml).is_file():
        raise UsageError(f"--map: no such file: {args.map_yaml}")
    if args.record is not None and args.record.is_dir():
        raise UsageError(f"--record takes a file to write (FILE.mcap), got the directory "
                         f"{args.record}")
    cfg = _load(args)
    sargs = ScenarioArgs(
        map_yaml=args.map_yaml, start=start, goal=goal, seed=args.seed, speed=speed,
        duration_s=args.duration, web=args.web, record=args.record, visitors=args.visitors,
    )

    async def announce(app: Any) -> None:
        if app.web_url:
            print(f"dashboard: {app.web_url}", flush=True)

    report = asyncio.run(run_scenario(scenario, cfg, sargs, args.report, on_app=announce))
    verdict = "succeeded" if report["success"] else f"FAILED: {report['failure']}"
    print(
        f"{report['scenario']} (seed {report['seed']}) {verdict}\n"
        f"  sim {report['sim_time_s']:.1f} s in {report['wall_time_s']:.2f} s wall; "
        f"goals {report['goals_reached']}/{report['goals_total']}; "
        f"collisions {report['collisions']}; path {report['path_length_m']:.2f} m; "
        f"localisation RMSE {report['localization_rmse_m']}"
    )
    for key, value in report.get("metrics", {}).items():
        _print_metric(key, value)
    for check in report.get("checks", []):
        mark = "ok  " if check["ok"] else "FAIL"
        print(f"  [{mark}] {check['name']} {check['detail']}")
    if args.report:
        print(f"  report: {args.report}")
    if args.record:
        print(f"  recording: {args.record}")
    return 0 if report["success"] else 1


def _print_metric(key: str, value: Any) -> None:
    """One metric of a scenario report: a list of records one line each, key=value."""
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        print(f"  {key}:")
        for item in value:
            print("    " + ", ".join(f"{k}={v}" for k, v in item.items()))
    else:
        print(f"  {key}: {value}")


def _announce(mode: str, web_url: str | None) -> None:
    """The banner printed once the rover runs: what runs and where the dashboard is."""
    what = {"sim": "the simulated rover", "emulated": "the rover on device emulators",
            "real": "the rover"}.get(mode, "the rover")
    lines = [f"Curio is running {what} (drivers.mode={mode})."]
    if web_url:
        view = web_url.split("?", 1)[0]
        lines += [f"dashboard: {web_url}", f"watch only: {view}"]
    lines.append("Ctrl-C stops the rover and exits.")
    print("\n" + "\n".join(lines) + "\n", flush=True)


def _cmd_run(args: argparse.Namespace) -> int:
    from curio.app import App
    from curio.commands.host import MapHost
    from curio.commands.signals import stop_on_signals
    from curio.core.clock import Clock, RealClock, SimClock
    from curio.drivers.modes import driver_mode

    cfg = _load(args)
    from curio.commands.warmup import config_args, prepare

    # the compiled kernels loaded (or compiled) before the start
    prepare(cfg, config_args(args.config, args.overrides))
    clock: Clock
    sim_clock: SimClock | None = None
    if driver_mode(cfg).world and cfg.sim.speed is not None:
        sim_clock = SimClock(speed=cfg.sim.speed)
        clock = sim_clock
    else:
        clock = RealClock()

    async def main() -> int:
        # With the map library (maps.enabled) the host builds the App on the active map and
        # rebuilds it to switch maps (curio/commands/host.py, docs/maps.md).
        host = MapHost(cfg, clock) if cfg.maps.enabled else None
        app = await host.start() if host is not None else App(cfg, clock)
        stop = stop_on_signals()
        if host is None:
            await app.start()
        _announce(cfg.drivers.mode, app.web_url)
        runner = asyncio.create_task(sim_clock.run(stop=stop.is_set)) if sim_clock else None
        waiter = asyncio.create_task(stop.wait())
        changes = asyncio.create_task(host.serve(stop)) if host is not None else None
        while not stop.is_set():
            await asyncio.wait({waiter}, timeout=0.5)
            app = host.app if host is not None and host.app is not None else app
            if app.failed_parts():
                name, exc = app.failed_parts()[0]
                log.error("stopping: %s failed: %s", name, exc)
                stop.set()
        log.info("stopping the rover")
        if changes is not None:
            with contextlib.suppress(Exception):
                await changes
            app = host.app if host is not None and host.app is not None else app
        await app.stop()
        if runner is not None:
            runner.cancel()
        return 1 if app.failed_parts() else 0

    return asyncio.run(main())


def _cmd_bench(args: argparse.Namespace) -> int:
    from curio.commands.bench import BenchOptions, dumps, format_table, run_benchmark

    extra: dict[str, Any] = {}
    for item in args.extra:
        if "=" not in item:
            raise UsageError(f"--set takes KEY=VALUE, got '{item}'")
        key, _, value = item.partition("=")
        extra[key.strip()] = value.strip()
    if args.seed < 0:
        raise UsageError(f"--seed takes a whole number >= 0, got {args.seed}")
    if args.pairs is not None and args.pairs <= 0:
        raise UsageError(f"--pairs takes a whole number > 0, got {args.pairs}")
    if args.map_yaml is not None and not Path(args.map_yaml).is_file():
        raise UsageError(f"--map: no such file: {args.map_yaml}")
    opts = BenchOptions(map_yaml=args.map_yaml, pairs=args.pairs, seed=args.seed, extra=extra)
    try:
        result = run_benchmark(args.name, opts, args.json)
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from None
    print(f"benchmark {result['benchmark']} on {result['machine']} at {result['date']}")
    print(format_table(result["rows"]))
    if args.json:
        print(f"wrote {args.json}")
    elif not sys.stdout.isatty():
        pass
    _ = dumps
    return 0


def _delegate(command: str, rest: list[str]) -> int:
    """Hand ``check``, ``emulate``, ``map``, ``replay``, ``export``, ``token``, ``pose``,
    ``zones``, ``fleet`` and ``warmup`` to the modules that own them."""
    import importlib

    module_name = {
        "check": "curio.commands.check",
        "emulate": "curio.commands.emulate",
        "map": "curio.commands.map",
        "replay": "curio.commands.replay",
        "export": "curio.commands.export",
        "token": "curio.commands.token",
        "pose": "curio.commands.pose",
        "zones": "curio.commands.zones",
        "fleet": "curio.commands.fleet",
        "warmup": "curio.commands.warmup",
    }[command]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name:
            print(f"curio {command}: not available in this build", file=sys.stderr)
            return 2
        raise
    result: int = module.main(rest)
    return result


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``curio`` command; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    verbose = bool(argv) and argv[0] in ("-v", "--verbose")
    rest = argv[1:] if verbose else argv
    if rest and rest[0] in _DELEGATED:
        # check / emulate / map / token / fleet parse their own arguments (--help included).
        _setup_logging(verbose)
        return _delegate(rest[0], rest[1:])
    parser = _build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args.verbose)
    try:
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "sim":
            return _cmd_sim(args)
        if args.command == "config":
            return _cmd_config(args)
        if args.command == "bench":
            return _cmd_bench(args)
        if args.command == "report":
            from curio.commands.report import run as report_run

            return report_run(_load(args), args)
        if args.command == "soak":
            from curio.commands.soak import run as soak_run

            return soak_run(args)
        return _delegate(args.command, args.rest)
    except ConfigError as exc:
        print(f"curio: {exc}", file=sys.stderr)
        return 2
    except UsageError as exc:
        print(f"curio {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except SetupError as exc:
        print(f"curio {args.command}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


_DELEGATED = ("check", "emulate", "map", "replay", "export", "token", "pose", "zones",
              "fleet", "warmup")


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
