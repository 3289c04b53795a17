"""The ``curio bench`` harness: finds a benchmark, runs it, prints a table, writes JSON.

Benchmarks live in ``benchmarks/bench_<name>.py`` at the repository root. Each defines
``run(opts: BenchOptions) -> list[dict]``: one row per subject (``"subject": "curio"`` or a
peer's name) with figures whose names carry their units (``median_ms``, ``p99_ms``,
``success_rate``, ``cpu_fraction``, ``rtf``, ...).
"""

from __future__ import annotations

import importlib
import json
import os
import platform
import sys
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from curio.core.config import REPO_ROOT
from curio.core.fileio import atomic_write_json

__all__ = ["BenchOptions", "available_benchmarks", "machine_info", "prepare_kernels",
           "run_benchmark"]


@dataclass
class BenchOptions:
    """Options common to every benchmark (each uses what applies to it)."""

    map_yaml: str | None = None
    pairs: int | None = None
    seed: int = 1
    extra: dict[str, Any] = field(default_factory=dict)


def _bench_dir() -> Path:
    return REPO_ROOT / "benchmarks"


def available_benchmarks() -> list[str]:
    """Names of the benchmarks found in ``benchmarks/`` (``bench_pi_budget.py`` is
    ``pi-budget``)."""
    return sorted(p.stem.removeprefix("bench_").replace("_", "-")
                  for p in _bench_dir().glob("bench_*.py"))


def machine_info() -> str:
    """A one-line description of this machine (CPU model, cores, Python)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def format_table(rows: list[dict[str, Any]]) -> str:
    """Render rows as an aligned text table (columns in first-seen order)."""
    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)

    def cell(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.4g}"
        return "" if value is None else str(value)

    widths = [max(len(c), *(len(cell(r.get(c))) for r in rows)) for c in columns]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    for row in rows:
        lines.append("  ".join(cell(row.get(c)).ljust(w) for c, w in zip(columns, widths,
                                                                          strict=True)))
    return "\n".join(lines)


def prepare_kernels() -> None:
    """Before a benchmark times the whole application: load every compiled kernel from the
    cache, compiling the missing ones first with ``curio warmup`` (what ``curio run`` does at
    its start). Without it a kernel that an untimed warm-up happens not to reach compiles
    inside the timed run on a fresh checkout."""
    from curio.commands.warmup import prepare
    from curio.core.config import load_config

    config = REPO_ROOT / "config.toml"
    prepare(load_config(config), ["--config", str(config)])


def run_benchmark(name: str, opts: BenchOptions, json_path: Path | None = None) -> dict[str, Any]:
    """Run benchmark ``name`` and return ``{"benchmark", "date", "machine", "rows"}``.

    Raises:
        KeyError: unknown benchmark (the message lists the known ones).
    """
    if name not in available_benchmarks():
        raise KeyError(f"unknown benchmark '{name}'; known: {', '.join(available_benchmarks())}")
    if str(REPO_ROOT) not in sys.path:
        sys.path.insert(0, str(REPO_ROOT))
    module = importlib.import_module(f"benchmarks.bench_{name.replace('-', '_')}")
    rows: list[dict[str, Any]] = module.run(opts)
    result = {
        "benchmark": name,
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": machine_info(),
        "rows": rows,
    }
    if json_path is not None:
        atomic_write_json(json_path, result)
    return result


def dumps(result: dict[str, Any]) -> str:
    """The result as JSON text."""
    return json.dumps(result, indent=2)
