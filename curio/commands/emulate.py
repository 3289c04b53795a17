"""``curio emulate DEVICE``: serve one device emulator on a pseudo-terminal for any client.

    curio emulate rplidar|arduino [--config PATH] [--map YAML] [--seed N] [--set KEY=VALUE]...
                                  [--link PATH] [--duration S]

It builds the simulator world from the configuration (``sim.world``, or ``--map``), runs its
physics in real time (the Arduino emulator's servo commands move the simulated rover; the
lidar sees the world from the rover's pose), starts the emulator, prints the device path (a
stable symlink; ``--link`` chooses it) and serves until Ctrl-C (or ``--duration`` seconds).

A pseudo-terminal has no modem-control lines: the RPLidar's motor, which the A1 switches with
DTR, is always spinning here, and clients that set DTR get ``ENOTTY`` from the kernel (pyserial
ignores that on open; libraries that call ``setDTR`` themselves need to tolerate it).

Exit codes: 0 after Ctrl-C or ``--duration``, 2 on bad arguments or configuration.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
from pathlib import Path
from typing import Any

from curio.core.clock import RealClock
from curio.core.config import ConfigError, load_config

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="curio emulate",
        description="Serve a device emulator on a pseudo-terminal, fed by the simulator.",
    )
    ap.add_argument("device", choices=["rplidar", "arduino"], help="which device to emulate")
    ap.add_argument("--config", help="config file (default: ./config.toml or the shipped one)")
    ap.add_argument("--map", dest="map_yaml", help="world map YAML (overrides sim.world)")
    ap.add_argument("--seed", type=int, help="simulator seed (overrides sim.seed)")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    metavar="KEY=VALUE", help="config override (repeatable)")
    ap.add_argument("--link", help="where to make the device symlink (default: a temp dir)")
    ap.add_argument("--duration", type=float, help="stop after this many seconds")
    return ap


async def _serve(args: argparse.Namespace, cfg: Any) -> int:
    from curio.sim.world import World

    clock = RealClock()
    world = World.from_config(cfg)
    link = Path(args.link).expanduser().absolute() if args.link else None
    if link is not None:
        link.parent.mkdir(parents=True, exist_ok=True)
    emulator: Any
    if args.device == "rplidar":
        from curio.drivers.rplidar.emulator import RplidarEmulator

        emulator = RplidarEmulator(
            world.cast_scan,
            clock,
            rate_hz=cfg.sim.lidar_rate_hz,
            seed=cfg.sim.seed,
            link_dir=link.parent if link else None,
            name=link.name if link else "curio-lidar",
            motor_on=True,
        )
        emulator.open()
        path, what = emulator.path, "RPLidar A1M8 (115200 baud; motor always on: no DTR on a pty)"
    else:
        from curio.drivers.arduino.emulator import ArduinoEmulator

        emulator = ArduinoEmulator(
            world,
            clock,
            seed=cfg.sim.seed,
            link_dir=link.parent if link else None,
            name=link.name if link else "curio-arduino",
        )
        emulator.open()
        path, what = emulator.port_path, "Arduino Mega base controller (115200 baud)"
    print(f"{what} emulator on {path}", flush=True)
    print(f"world {cfg.sim.world}, seed {cfg.sim.seed}; Ctrl-C to stop", flush=True)

    async def physics() -> None:
        dt = 1.0 / cfg.sim.physics_rate_hz
        async for _ in clock.every(dt):
            world.step(dt)

    tasks = [asyncio.create_task(emulator.run()), asyncio.create_task(physics())]
    try:
        if args.duration is not None:
            await clock.sleep(args.duration)
        else:
            await asyncio.gather(*tasks)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        closer = getattr(emulator, "aclose", None) or emulator.close
        result = closer()
        if asyncio.iscoroutine(result):
            await result
    return 0


def main(argv: list[str]) -> int:
    """Run ``curio emulate``; return the exit code."""
    args = _parser().parse_args(argv)
    overrides = list(args.overrides)
    if args.map_yaml:
        if not Path(args.map_yaml).is_file():
            print(f"curio emulate: --map: no such file: {args.map_yaml}", file=sys.stderr)
            return 2
        overrides.append(f'sim.world="{Path(args.map_yaml).resolve()}"')
    if args.seed is not None:
        overrides.append(f"sim.seed={args.seed}")
    if args.duration is not None and args.duration <= 0:
        print("curio emulate: --duration takes seconds > 0", file=sys.stderr)
        return 2
    try:
        cfg = load_config(args.config, overrides)
    except ConfigError as exc:
        print(f"curio emulate: {exc}", file=sys.stderr)
        return 2
    with contextlib.suppress(KeyboardInterrupt):
        return asyncio.run(_serve(args, cfg))
    print("stopped", flush=True)
    return 0
