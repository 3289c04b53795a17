"""``curio report --day YYYY-MM-DD``: the daily report from the event log.

    curio report --day YYYY-MM-DD [--json] [--csv FILE] [--config PATH] [--set KEY=VALUE]...

Reads ``<data_dir>/<eventlog.file>`` (read-only: it may run beside the rover) and prints the
day's report in the building's time zone (``tours.timezone``); ``--json`` prints it as JSON,
``--csv FILE`` also writes that day's records as CSV. Exit codes: 0, or 2 with one line for a
bad date, a bad config or a missing or unusable event log.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path
from zoneinfo import ZoneInfo

from curio.core.config import Config
from curio.core.errors import SetupError
from curio.eventlog.report import daily_report, day_bounds, format_report
from curio.eventlog.store import EventLog, LogQuery

__all__ = ["add_arguments", "parse_day", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command's own arguments (the config ones are added by the CLI)."""
    parser.add_argument("--day", required=True, help="the local day, YYYY-MM-DD")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--csv", type=Path, help="also write the day's records to this CSV")


def parse_day(text: str) -> dt.date:
    """``YYYY-MM-DD`` as a date (:class:`SetupError` with the allowed form otherwise)."""
    try:
        return dt.date.fromisoformat(text.strip())
    except ValueError:
        raise SetupError(f"--day {text!r} is not a date; use YYYY-MM-DD, e.g. "
                         f"{dt.date(2025, 6, 2).isoformat()}") from None


def run(cfg: Config, args: argparse.Namespace) -> int:
    """Print the report; return the exit code."""
    day = parse_day(args.day)
    tz = ZoneInfo(cfg.tours.timezone)
    path = cfg.resolve(cfg.data_dir) / cfg.eventlog.file
    log = EventLog(path, readonly=True)
    report = daily_report(log, day, tz)
    if args.json:
        print(json.dumps(report.to_json(), indent=2, ensure_ascii=False))
    else:
        print(format_report(report), end="")
    if args.csv is not None:
        since, until = day_bounds(day, tz)
        try:
            with open(args.csv, "w", encoding="utf-8", newline="") as fh:
                n = log.export_csv(fh, LogQuery(since_wall_s=since, until_wall_s=until,
                                                limit=100_000), tz)
        except OSError as exc:
            raise SetupError(f"--csv {args.csv}: cannot write ({exc.strerror})") from None
        print(f"wrote {n} records to {args.csv}", file=sys.stderr)
    return 0
