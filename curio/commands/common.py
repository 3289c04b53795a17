"""What the delegated commands (``curio replay``, ``curio export``) share: parse the arguments,
run, and turn a mistake the user can fix into one line and exit code 2."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TextIO

from curio.core.errors import SetupError
from curio.estimation.carmen import LogError

__all__ = ["run_command"]

Body = Callable[[argparse.Namespace, TextIO, TextIO], int]


def run_command(name: str, parser: argparse.ArgumentParser, argv: list[str] | None,
                out: TextIO | None, err: TextIO | None, body: Body) -> int:
    """Parse ``argv`` (``--help``: exit 0; bad arguments: argparse's message, exit 2), then
    return ``body(args, out, err)``; a :class:`SetupError` or :class:`LogError` it raises is
    one line ``curio NAME: error: ...`` on ``err`` and exit code 2."""
    out = out or sys.stdout
    err = err or sys.stderr
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return 0 if exc.code == 0 else 2
    try:
        return body(args, out, err)
    except (SetupError, LogError) as exc:
        err.write(f"curio {name}: error: {' '.join(str(exc).split())}\n")
        return 2
