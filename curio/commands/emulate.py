"""``curio emulate DEVICE``: serve one device emulator on a pseudo-terminal for any client.

    curio emulate rplidar|arduino [--config PATH] [--map YAML] [--seed N] [--set KEY=VALUE]...
                                  [--link PATH] [--duration S]

It builds the simulator world from the configuration (``sim.world``, or ``--map``), runs its
physics in real time (the Arduino emulator's servo commands move the simulated rover; the
lidar sees the world from the rover's pose), starts the emulator (the same class, built the
same way, as ``drivers.mode = "emulated"`` does: ``LIDAR`` and ``BASE`` in
``curio/drivers/wiring.py``), prints the device path (a stable symlink; ``--link`` chooses it)
and serves until Ctrl-C (or ``--duration`` seconds).

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

from curio.commands.signals import stop_on_signals
from curio.core.clock import RealClock
from curio.core.config import Config, ConfigError, load_config
from curio.core.errors import SetupError
from curio.drivers.wiring import BASE, LIDAR

# The devices served on a pseudo-terminal, in the usage line's order (the BNO055's emulator is
# an in-memory I2C bus).
SERVED = {device.name: device for device in (LIDAR, BASE)}

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="curio emulate",
        description="Serve a device emulator on a pseudo-terminal, fed by the simulator.",
    )
    ap.add_argument("device", choices=list(SERVED), help="which device to emulate")
    ap.add_argument("--config", help="config file (default: ./config.toml or the shipped one)")
    ap.add_argument("--map", dest="map_yaml", help="world map YAML (overrides sim.world)")
    ap.add_argument("--seed", type=int, help="simulator seed (overrides sim.seed)")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    metavar="KEY=VALUE", help="config override (repeatable)")
    ap.add_argument("--link", help="where to make the device symlink (default: a temp dir)")
    ap.add_argument("--duration", type=float, help="stop after this many seconds")
    return ap


async def _serve(args: argparse.Namespace, cfg: Config) -> int:
    from curio.sim.world import World

    stop = stop_on_signals()
    clock = RealClock()
    world = World.from_config(cfg)
    link = Path(args.link).expanduser().absolute() if args.link else None
    if link is not None:
        link.parent.mkdir(parents=True, exist_ok=True)
    device = SERVED[args.device]
    emulator = device.emulator(world, clock, cfg, cfg.sim.seed, link)
    emulator.open()
    print(f"{device.serves} emulator on {emulator.path}", flush=True)
    print(f"world {cfg.sim.world}, seed {cfg.sim.seed}; Ctrl-C to stop", flush=True)

    async def physics() -> None:
        dt = 1.0 / cfg.sim.physics_rate_hz
        async for _ in clock.every(dt):
            world.step(dt)

    parts = emulator.parts()
    tasks: list[asyncio.Future[None]] = [
        asyncio.ensure_future(part.run()) for part in parts if part.run is not None]
    tasks.append(asyncio.ensure_future(physics()))
    async def stopped() -> None:
        await stop.wait()

    waiters: list[asyncio.Future[None]] = [asyncio.ensure_future(stopped())]
    if args.duration is not None:
        waiters.append(asyncio.ensure_future(clock.sleep(args.duration)))
    try:
        done, _ = await asyncio.wait([*waiters, *tasks], return_when=asyncio.FIRST_COMPLETED)
        for fut in done:
            if fut not in waiters:
                fut.result()  # an emulator part that ended: its error, if it had one
    finally:
        for task in [*waiters, *tasks]:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for part in parts:
            if part.close is not None:
                await part.close()
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
    if args.seed is not None and args.seed < 0:
        print(f"curio emulate: --seed takes a whole number >= 0, got {args.seed}",
              file=sys.stderr)
        return 2
    try:
        with contextlib.suppress(KeyboardInterrupt):
            return asyncio.run(_serve(args, cfg))
    except SetupError as exc:  # a missing or corrupt world map
        print(f"curio emulate: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print("stopped", flush=True)
    return 0
