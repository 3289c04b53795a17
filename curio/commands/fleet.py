"""``curio fleet``: the fleet manager, the fleet simulator, keys and signed commands.

    curio fleet run [--config PATH] [--set KEY=VALUE]...
    curio fleet sim [--rovers N] [--scenario tour-day|doorway|disconnect] [--seed N]
                    [--speed N|max] [--duration S] [--report PATH]
                    [--transport zenoh|memory] [--processes] [--config PATH] [--set ...]
    curio fleet key create NAME --role kiosk|operator|admin [--secret S] | list | revoke NAME
    curio fleet send ROVER ACTION [--x X --y Y --yaw YAW] [--tour-id N] [--key NAME]

``run`` opens the manager's Zenoh session (``fleet.manager.mode``/``listen``/``connect``),
serves the fleet page and JSON API on ``fleet.manager.host``:``port`` and runs until Ctrl-C.
``sim`` runs a fleet scenario on simulated time (exit 0 success, 1 failure) or, with
``--processes``, the rovers as separate ``curio run`` processes on real time
(:mod:`curio.commands.fleet_procs`). ``key`` edits ``<data_dir>/<fleet.keys_file>``; ``send``
signs one command with a key of it, sends it and prints the rover's reply. Every mistake is
one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
from pathlib import Path
from typing import Any

from curio.core.config import Config, ConfigError, load_config
from curio.core.errors import SetupError

__all__ = ["main"]

log = logging.getLogger("curio.fleet")


class _Usage(Exception):
    """A bad argument (exit 2)."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="curio fleet", description="a fleet of rovers over Zenoh")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="ACTION")
    for name, helptext in (("run", "run the fleet manager"),
                           ("sim", "run a fleet scenario"),
                           ("key", "manage the fleet's named keys"),
                           ("send", "send a signed command to a rover")):
        s = sub.add_parser(name, help=helptext)
        s.add_argument("--config", type=Path, help="config TOML")
        s.add_argument("--set", dest="overrides", action="append", default=[],
                       metavar="KEY=VALUE", help="override one config key (repeatable)")
        if name == "sim":
            s.add_argument("--rovers", type=int, help="number of rovers (default: the "
                                                      "scenario's)")
            s.add_argument("--scenario", default="tour-day", help="tour-day, doorway, "
                                                                 "disconnect")
            s.add_argument("--seed", type=int, default=1, help="random seed >= 0")
            s.add_argument("--speed", default="max", help="N x real time, or max")
            s.add_argument("--duration", type=float, help="time limit, simulated seconds")
            s.add_argument("--report", type=Path, help="write the JSON report here")
            s.add_argument("--transport", default="zenoh", help="zenoh (default) or memory")
            s.add_argument("--processes", action="store_true",
                           help="each rover a separate 'curio run' on real time")
        elif name == "key":
            s.add_argument("key_action", choices=("create", "list", "revoke"))
            s.add_argument("name", nargs="?")
            s.add_argument("--role", default="operator", help="kiosk, operator or admin")
            s.add_argument("--secret", help="use this secret (copy a manager's key to a rover)")
        elif name == "send":
            s.add_argument("rover")
            s.add_argument("action")
            s.add_argument("--x", type=float)
            s.add_argument("--y", type=float)
            s.add_argument("--yaw", type=float)
            s.add_argument("--tour-id", type=int)
            s.add_argument("--key", default=None, help="key name (default fleet.manager."
                                                        "key_name)")
            s.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the "
                                                                      "reply")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run ``curio fleet`` with ``argv`` (without the ``fleet`` word); return the exit code."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return 0 if exc.code == 0 else 2
    try:
        cfg = load_config(args.config, args.overrides)
        if args.cmd == "run":
            return _run(cfg)
        if args.cmd == "sim":
            return _sim(cfg, args)
        if args.cmd == "key":
            return _key(cfg, args)
        return _send(cfg, args)
    except ConfigError as exc:
        print(f"curio: {exc}", file=sys.stderr)
        return 2
    except (_Usage, SetupError) as exc:
        print(f"curio fleet {args.cmd}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def _speed(text: str) -> float | None:
    if text == "max":
        return None
    try:
        value = float(text)
    except ValueError:
        raise _Usage(f"--speed takes a number > 0 or 'max', got '{text}'") from None
    if not value > 0:
        raise _Usage(f"--speed takes a number > 0 or 'max', got '{text}'")
    return value


def _sim(cfg: Config, args: argparse.Namespace) -> int:
    from curio.scenarios.fleet import get_fleet_scenario
    from curio.scenarios.fleet.base import FleetArgs, run_fleet

    try:
        scenario = get_fleet_scenario(args.scenario)
    except KeyError as exc:
        raise _Usage(str(exc.args[0])) from None
    if args.rovers is not None and not 1 <= args.rovers <= 6:
        raise _Usage(f"--rovers takes 1 to 6, got {args.rovers}")
    if args.seed < 0:
        raise _Usage(f"--seed takes a whole number >= 0, got {args.seed}")
    if args.duration is not None and not args.duration > 0:
        raise _Usage(f"--duration takes simulated seconds > 0, got {args.duration}")
    if args.transport not in ("zenoh", "memory"):
        raise _Usage(f"--transport takes zenoh or memory, got '{args.transport}'")
    speed = _speed(args.speed)
    if args.processes:
        from curio.commands.fleet_procs import run_processes

        return int(run_processes(cfg, scenario, args))
    if args.transport == "zenoh":
        from curio.fleet.zenoh_link import load_zenoh

        load_zenoh()
    try:
        fargs = FleetArgs(args.rovers, args.seed, speed, args.duration, args.transport)
        report = asyncio.run(run_fleet(scenario, cfg, fargs, args.report))
    except ValueError as exc:
        raise _Usage(str(exc)) from None
    _print_report(report, args.report)
    return 0 if report["success"] else 1


def _print_report(report: dict[str, Any], path: Path | None) -> None:
    verdict = "succeeded" if report["success"] else f"FAILED: {report['failure']}"
    m = report["metrics"]
    print(f"fleet {report['scenario']} ({report['rovers']} rovers, seed {report['seed']}, "
          f"{report['transport']}) {verdict}\n  sim {report['sim_time_s']:.1f} s in "
          f"{report['wall_time_s']:.1f} s wall; collisions {report['collisions']}")
    for key in ("tours_requested", "tours_completed", "tours_dropped", "redispatches",
                "rover_rover_collisions", "rover_rover_encounters", "longest_standoff_s",
                "time_to_both_s"):
        if key in m:
            print(f"  {key}: {m[key]}")
    for r in report["per_rover"]:
        link: dict[str, Any] = next((x for x in m.get("link", [])
                                     if x["rover"] == r["rover"]), {})
        print(f"  {r['rover']}: tours {r['tours_completed']}, encounters {r['encounters']}, "
              f"longest wait {r['longest_wait_s']} s, link {link.get('msgs_per_s')} msg/s "
              f"{link.get('bytes_per_s')} B/s")
    for check in report["checks"]:
        print(f"  [{'ok  ' if check['ok'] else 'FAIL'}] {check['name']} {check['detail']}")
    if path is not None:
        print(f"  report: {path}")


def _key(cfg: Config, args: argparse.Namespace) -> int:
    from curio.fleet.auth import FleetKeyring

    ring = FleetKeyring(cfg.data_path(cfg.fleet.keys_file))
    if args.key_action == "list":
        for k in ring.entries():
            print(f"{k.name}\t{k.role}\t…{k.secret[-4:]}")
        return 0
    if not args.name:
        raise _Usage(f"'key {args.key_action}' needs a NAME")
    if args.key_action == "create":
        entry = ring.add(args.name, args.role, args.secret)
        print(f"created fleet key {entry.name!r} ({entry.role}) in {ring.path}\n"
              f"secret: {entry.secret}\n(copy it to each rover with: curio fleet key create "
              f"{entry.name} --role {entry.role} --secret <secret>)")
        return 0
    entry = ring.revoke(args.name)
    print(f"revoked fleet key {entry.name!r}")
    return 0


def _command(args: argparse.Namespace) -> dict[str, Any]:
    from curio.fleet.commands import ACTIONS

    if args.action not in ACTIONS:
        raise _Usage(f"ACTION must be one of {', '.join(ACTIONS)}, got '{args.action}'")
    cmd: dict[str, Any] = {"action": args.action, "request_id": f"cli-{id(args):x}"}
    if args.action == "goto":
        if args.x is None or args.y is None:
            raise _Usage("goto needs --x and --y (metres in map)")
        cmd.update({"x": args.x, "y": args.y, "yaw": args.yaw if args.yaw is not None else 0.0})
    if args.tour_id is not None:
        cmd["tour_id"] = args.tour_id
    return cmd


def _send(cfg: Config, args: argparse.Namespace) -> int:
    from curio.core.clock import RealClock, wall_sleep
    from curio.fleet import codec
    from curio.fleet.auth import CommandSigner, FleetKeyring
    from curio.fleet.keys import check_rover_name, rover_key
    from curio.fleet.wiring import zenoh_settings
    from curio.fleet.zenoh_link import ZenohTransport, load_zenoh

    load_zenoh()
    try:
        rover = check_rover_name(args.rover)
    except ValueError as exc:
        raise _Usage(str(exc)) from None
    cmd = _command(args)
    name = args.key or cfg.fleet.manager.key_name
    key = FleetKeyring(cfg.data_path(cfg.fleet.keys_file)).key(name)
    if key is None:
        raise _Usage(f"no fleet key named {name!r} in {cfg.data_path(cfg.fleet.keys_file)} "
                     "(curio fleet key create NAME --role operator)")
    settings = zenoh_settings(cfg)
    transport = ZenohTransport("cli", settings)
    replies: list[dict[str, Any]] = []
    transport.subscribe(rover_key(rover, "reply"), lambda s: replies.append(codec.loads(s.payload)))
    transport.open()
    clock = RealClock()
    try:
        wall_sleep(0.5)  # let the session find the routes
        transport.put(rover_key(rover, "cmd"), CommandSigner(key, clock.wall_time).sign(rover, cmd))
        waited = 0.0
        while waited < args.timeout:
            transport.pump()
            mine = [r for r in replies if r.get("request_id") in (cmd["request_id"], "")]
            if mine:
                print(json.dumps(mine[0]))
                return 0 if mine[0].get("ok") else 1
            wall_sleep(0.1)
            waited += 0.1
    finally:
        transport.close()
    print(f"no reply from {rover} within {args.timeout:g} s", file=sys.stderr)
    return 1


def _run(cfg: Config) -> int:
    from curio.commands.signals import stop_on_signals
    from curio.core.clock import RealClock
    from curio.fleet.auth import FleetKeyring
    from curio.fleet.manager.service import FleetManager
    from curio.fleet.manager.web import FleetWeb, load_or_create_token
    from curio.fleet.zenoh_link import ZenohSettings, ZenohTransport, load_zenoh

    load_zenoh()
    m = cfg.fleet.manager
    ring = FleetKeyring(cfg.data_path(cfg.fleet.keys_file))
    key = ring.key(m.key_name) or ring.add(m.key_name, "operator")
    transport = ZenohTransport("manager", ZenohSettings(m.mode, tuple(m.connect),
                                                        tuple(m.listen)), threaded_puts=True)
    clock = RealClock()

    async def main() -> int:
        manager = FleetManager(cfg, clock, transport, key)
        token = load_or_create_token(cfg.data_path("fleet_manager_token"))
        manager.web = FleetWeb(manager, m.host, m.port, token)
        stop = stop_on_signals()
        await manager.start()
        print(f"\nCurio fleet manager on {', '.join(m.listen) or 'its Zenoh session'}\n"
              f"fleet page: http://{m.host}:{m.port}/?token={token}\n"
              f"signing key: {key.name!r} (give the rovers its secret: curio fleet key list)\n"
              "Ctrl-C stops it.\n", flush=True)
        while not stop.is_set():
            await clock.sleep(0.5)
            if manager.failed_parts():
                log.error("stopping: %s failed", manager.failed_parts()[0][0])
                break
        await manager.stop()
        transport.close()
        return 1 if manager.failed_parts() else 0

    return asyncio.run(main())
