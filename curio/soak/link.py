"""The line protocol between the soak's rover (child) and its orchestrator (parent).

The rover writes one JSON object per line to its standard output; each has ``t`` (its type)
and ``boot`` (how many times the rover was started before). Types:

* ``hello`` — the rover runs: ``port`` (the dashboard), ``pid``, ``sim_s``, ``wall_s``;
* ``beat`` — every ``BEAT_S`` of simulated time: ``sim_s`` (the clock's ``now()``), ``wall_s``
  (the building's clock), ``truth`` ``[x, y, yaw]`` (the simulated rover, ``map``), ``v_mps``,
  ``battery_v``, ``tour`` (the running tour's id or null), ``status``, ``estop``,
  ``lapsed_s`` (building time skipped while parked, in total);
* ``ev`` — an event the ledger or the report needs (``kind``, ``sim_s``, ``wall_s``,
  ``detail``): operator commands as published (``operator``), the tree's answers, tours,
  collisions, help requests, the rover's own reports after a restart;
* ``fault`` — a fault injected (``phase: injected``) or judged (``phase: result``);
* ``res`` — a resource and timing sample (:mod:`curio.soak.probes`);
* ``kill_me`` — a ``kill9`` (or ``corrupt_file``) fault is due now: the parent kills the rover;
* ``done`` — the soak's end was reached (the rover then stops cleanly).

The orchestrator writes ``{"t": "stop"}`` to the rover's standard input to end it cleanly.
"""

from __future__ import annotations

import json
import sys
from typing import Any, TextIO

from curio.core.jsonable import to_jsonable

__all__ = ["BEAT_S", "Link", "parse_line"]

BEAT_S = 0.5


class Link:
    """The rover's end: writes report lines (flushed at once, so a ``kill -9`` loses none that
    were written).

    Args:
        out: where lines go (the process's standard output).
        boot: this rover's start number (0 for the first).
    """

    def __init__(self, out: TextIO | None = None, boot: int = 0) -> None:
        self.out = out if out is not None else sys.stdout
        self.boot = boot
        self.lines = 0

    def send(self, t: str, /, **fields: Any) -> None:
        """Write one line ``{"t": t, "boot": ..., **fields}``."""
        obj = {"t": t, "boot": self.boot, **to_jsonable(fields, 6)}
        self.out.write(json.dumps(obj, separators=(",", ":"), allow_nan=False) + "\n")
        self.out.flush()
        self.lines += 1


def parse_line(line: str | bytes) -> dict[str, Any] | None:
    """One line from the rover as a dict, or None when it is not one of ours (a stray print)."""
    text = line.decode("utf-8", "replace") if isinstance(line, bytes) else line
    text = text.strip()
    if not text.startswith("{"):
        return None
    try:
        obj = json.loads(text)
    except ValueError:
        return None
    return obj if isinstance(obj, dict) and "t" in obj else None
