"""Errors the person running Curio can fix: a bad file, a busy port, a bad value.

The command line turns a :class:`SetupError` into one line on stderr and exit code 2 (no
traceback); its message names the value, what is wrong with it and what is allowed.
"""

from __future__ import annotations

__all__ = ["SetupError"]


class SetupError(Exception):
    """A problem with the setup (files, ports, values) that the user can fix."""
