"""System figures for the dashboard's health panel: CPU, temperature, event-loop lag.

:class:`SystemMonitor` reads ``/proc/stat`` and ``/sys/class/thermal`` when present (small
procfs reads, about once a second); :func:`measure_loop_lag_ms` times one turn of the event
loop on the wall clock.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from pathlib import Path
from typing import Any

from curio.core.clock import wall_perf_counter

__all__ = ["SystemMonitor", "measure_loop_lag_ms"]


class SystemMonitor:
    """CPU load, temperature, process CPU share and event-loop lag for the health panel.

    Reads ``/proc/stat`` and ``/sys/class/thermal`` when present (small procfs reads).
    """

    def __init__(self) -> None:
        self._cpu_prev: tuple[int, int] | None = None
        self._proc_prev: tuple[float, float] | None = None

    @staticmethod
    def _proc_stat() -> tuple[int, int] | None:
        try:
            with open("/proc/stat", encoding="ascii") as fh:
                fields = fh.readline().split()[1:]
        except OSError:
            return None
        values = [int(v) for v in fields]
        idle = values[3] + (values[4] if len(values) > 4 else 0)
        return sum(values), idle

    @staticmethod
    def temperature_c() -> float | None:
        """The hottest thermal zone, °C, or None when the machine has none."""
        base = Path("/sys/class/thermal")
        best: float | None = None
        with contextlib.suppress(OSError):
            for zone in base.glob("thermal_zone*/temp"):
                with contextlib.suppress(OSError, ValueError):
                    value = int(zone.read_text().strip()) / 1000.0
                    best = value if best is None else max(best, value)
        return best

    def sample(self, loop_lag_ms: float | None = None) -> dict[str, Any]:
        """One sample of the system figures (fractions 0..1, temperatures °C)."""
        out: dict[str, Any] = {"cpu_count": os.cpu_count() or 1}
        now = self._proc_stat()
        if now is not None and self._cpu_prev is not None:
            total = now[0] - self._cpu_prev[0]
            idle = now[1] - self._cpu_prev[1]
            out["cpu_fraction"] = round(1.0 - idle / total, 3) if total > 0 else 0.0
        self._cpu_prev = now
        wall = wall_perf_counter()
        times = os.times()
        proc = times.user + times.system
        if self._proc_prev is not None and wall > self._proc_prev[0]:
            out["process_cpu_fraction"] = round(
                (proc - self._proc_prev[1]) / (wall - self._proc_prev[0]), 3)
        self._proc_prev = (wall, proc)
        with contextlib.suppress(OSError):
            out["load_avg"] = [round(v, 2) for v in os.getloadavg()]
        out["temperature_c"] = self.temperature_c()
        if loop_lag_ms is not None:
            out["loop_lag_ms"] = round(loop_lag_ms, 2)
        return out


async def measure_loop_lag_ms() -> float:
    """How long a callback queued now waits for the event loop, in milliseconds (wall)."""
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[None] = loop.create_future()
    t0 = wall_perf_counter()
    loop.call_soon(fut.set_result, None)
    await fut
    return (wall_perf_counter() - t0) * 1000.0
