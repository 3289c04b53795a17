"""``curio soak``: days without a person (see :mod:`curio.soak`).

``curio soak [--hours H] [--clients N] [--faults N] [--seed N] [--report PATH]
[--workdir DIR] [--disk auto|tmpfs|none] [--kinds K,K...] [--start HH:MM] [--keep]
[--visitors N] [--config PATH] [--set KEY=VALUE]...``

Runs the whole rover in emulated mode on simulated time for ``--hours`` of the building's
clock (default 24) with ``--clients`` scripted dashboard clients (default 10), ``--visitors``
simulated visitors walking the building (default 6) and a campaign of ``--faults`` faults
(default 200) drawn from ``--seed``; prints a progress bar while it runs
(on a terminal; a line every 5 % otherwise), then the summary table, and writes the JSON report
to ``--report``. Exit code 0 when every check passed, 1 when one failed, 2 on bad arguments.
Ctrl-C (or SIGTERM) ends a soak early as at its end: the report covers what ran and fails
its check "ran its whole time"; a second Ctrl-C stops at once, without a report.
The rover's files and logs are kept in ``--workdir`` (default ``<data_dir>/soak``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime as dt
import math
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from curio.core.config import load_config
from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_json

if TYPE_CHECKING:  # pragma: no cover
    from curio.soak.orchestrator import Orchestrator

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``curio soak``'s arguments."""
    parser.add_argument("--hours", type=float, default=24.0,
                        help="simulated hours of the building's clock (default 24)")
    parser.add_argument("--clients", type=int, default=10,
                        help="scripted dashboard clients (default 10; at least 3)")
    parser.add_argument("--faults", type=int, default=200, help="faults in the campaign")
    parser.add_argument("--seed", type=int, default=1, help="random seed >= 0")
    parser.add_argument("--report", type=Path, help="write the JSON report here")
    parser.add_argument("--workdir", type=Path,
                        help="where the rover's files and logs go (default <data_dir>/soak)")
    parser.add_argument("--disk", choices=("auto", "tmpfs", "none"), default="auto",
                        help="the data filesystem: a size-limited tmpfs for the disk-full "
                             "faults (auto: when root can mount one)")
    parser.add_argument("--kinds",
                        help="only these fault kinds, comma-separated (default: all; see "
                             "docs/reliability.md)")
    parser.add_argument("--start", help="the building's local time at the start, HH:MM "
                                        "(default 07:50, before the first tour)")
    parser.add_argument("--visitors", type=int, default=6,
                        help="simulated visitors walking the building (default 6; 0: none)")
    parser.add_argument("--keep", action="store_true",
                        help="copy the rover's data directory out of the tmpfs at the end")


class Progress:
    """A progress bar on a terminal, a line every 5 % otherwise (standard error)."""

    def __init__(self, hours: float, tty: bool) -> None:
        self.hours = hours
        self.tty = tty
        self.last_step = -1

    def __call__(self, p: dict[str, Any]) -> None:
        """Show one update from the orchestrator."""
        frac = float(p["fraction"])
        wall = float(p["wall_s"])
        rate = frac * self.hours * 3600.0 / wall if wall > 0 else 0.0
        eta = (1.0 - frac) * wall / frac / 60.0 if frac > 0.001 else math.nan
        text = (f"{frac * 100:5.1f}% {frac * self.hours:5.2f} h · faults {p['faults']}/"
                f"{p['planned']} · restarts {p['boot']} · collisions {p['collisions']} · "
                f"commands {p['commands']} · {rate:4.1f}x · ETA {eta:4.0f} min")
        if self.tty:
            bar = "#" * int(frac * 30)
            sys.stderr.write(f"\r[{bar:<30}] {text}")
            sys.stderr.flush()
            return
        step = int(frac * 20)
        if step != self.last_step:
            self.last_step = step
            print(f"soak: {text}", file=sys.stderr, flush=True)

    def close(self) -> None:
        """End the bar's line."""
        if self.tty:
            sys.stderr.write("\n")


def _kinds(text: str | None) -> list[str] | None:
    """``--kinds``: known fault kinds, comma-separated."""
    from curio.soak.plan import KINDS

    if text is None:
        return None
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise SetupError(f"--kinds takes fault kinds from {', '.join(KINDS)}, got {text!r}")
    return kinds


def _start(text: str | None) -> dt.time | None:
    """``--start HH:MM``."""

    if text is None:
        return None
    try:
        return dt.time.fromisoformat(text)
    except ValueError:
        raise SetupError(f"--start takes a local time HH:MM, got {text!r}") from None


async def _run_stoppable(orchestrator: Orchestrator) -> None:
    """Run the soak; the first Ctrl-C or SIGTERM ends it early with a report of what ran, a
    second Ctrl-C stops at once (no report)."""
    loop = asyncio.get_running_loop()

    def stop(signame: str) -> None:
        orchestrator.stop_early(f"{signame} at {orchestrator.progress_text()}")
        print(f"\nsoak: {signame}: stopping, the report will cover what ran "
              "(Ctrl-C again to stop at once, without a report)", file=sys.stderr, flush=True)
        loop.remove_signal_handler(signal.SIGINT)  # the next Ctrl-C: KeyboardInterrupt

    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop, sig.name)
    await orchestrator.run()


def run(args: argparse.Namespace) -> int:
    """Run ``curio soak`` with parsed ``args``; return the exit code."""
    from curio.soak.orchestrator import Orchestrator, SoakOptions
    from curio.soak.report import build_report, format_table

    if not (0.0 < args.hours <= 24.0 * 14):
        raise SetupError(f"--hours takes simulated hours in (0, 336], got {args.hours}")
    if args.clients < 3:
        raise SetupError(f"--clients takes at least 3 (a viewer, an operator, a kiosk), got "
                         f"{args.clients}")
    if args.faults < 0:
        raise SetupError(f"--faults takes a whole number >= 0, got {args.faults}")
    if args.seed < 0:
        raise SetupError(f"--seed takes a whole number >= 0, got {args.seed}")
    if not 0 <= args.visitors <= 100:
        raise SetupError(f"--visitors takes a whole number 0..100, got {args.visitors}")
    kinds, start = _kinds(args.kinds), _start(args.start)
    cfg = load_config(args.config, args.overrides)
    workdir = args.workdir or cfg.resolve(cfg.data_dir) / "soak"
    progress = Progress(args.hours, sys.stderr.isatty())
    opts = SoakOptions(hours=args.hours, clients=args.clients, faults=args.faults,
                       seed=args.seed, config=args.config, overrides=list(args.overrides),
                       workdir=Path(workdir), disk=args.disk, keep=args.keep, kinds=kinds,
                       start=start, visitors=args.visitors,
                       progress=progress)
    orchestrator = Orchestrator(opts)
    try:
        asyncio.run(_run_stoppable(orchestrator))
    finally:
        progress.close()
    report = build_report(orchestrator)
    if args.report is not None:
        atomic_write_json(args.report, report)
    print(format_table(report))
    if args.report is not None:
        print(f"  report: {args.report}")
    return 0 if report["success"] else 1
