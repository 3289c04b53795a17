"""What the soak's rover measures about itself: memory, file descriptors, threads, queues, and
the control loop's cycle times and the safety stage's rate.

* **Resources** (:func:`resources`): resident set size (``/proc/self/statm``), open file
  descriptors (``/proc/self/fd``), threads (``/proc/self/status``), the longest subscriber
  queue of every bus topic (:meth:`curio.core.bus.Bus.backlog`), each dashboard client's
  queues (reliable messages waiting, stream slots), the flight recorder's queue and the event
  log's writer queue.
* **Cycle times** (:class:`CycleTimer`): the navigation cycle (``NavigatorNode.step``: the
  navigator's policies and the local controller) and the safety stage's step are wrapped on the
  instance (nothing in their modules changes) and timed twice: CPU time of the loop's thread
  (what the cycle costs, whatever else the machine runs) and wall time (what it took here,
  under the machine's load). Each goes into a log-scale histogram (:class:`Histogram`) that the
  orchestrator merges across restarts for percentiles.
* **Rate** (:class:`RateWatch`): the safety stage's steps per simulated second and its longest
  gap between two steps (simulated seconds), so a stalled loop shows.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from curio.core.clock import thread_cpu_time, wall_perf_counter

__all__ = ["CycleTimer", "Histogram", "RateWatch", "resources"]

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
BUCKETS_PER_DECADE = 20
LOW_S = 1e-6


@dataclass
class Histogram:
    """Durations (seconds) in log-scale buckets: ``BUCKETS_PER_DECADE`` per decade from
    ``LOW_S``; mergeable and small enough to send whole."""

    counts: dict[int, int] = field(default_factory=dict)
    n: int = 0
    max_s: float = 0.0

    def add(self, value_s: float) -> None:
        """Count one duration."""
        k = 0 if value_s <= LOW_S else int(math.log10(value_s / LOW_S) * BUCKETS_PER_DECADE)
        self.counts[k] = self.counts.get(k, 0) + 1
        self.n += 1
        self.max_s = max(self.max_s, value_s)

    def merge(self, other: Histogram) -> None:
        """Add ``other``'s counts to this one."""
        for k, c in other.counts.items():
            self.counts[k] = self.counts.get(k, 0) + c
        self.n += other.n
        self.max_s = max(self.max_s, other.max_s)

    def quantile(self, q: float) -> float:
        """The ``q`` quantile (0..1), as the upper edge of its bucket (seconds; 0 if empty)."""
        if self.n == 0:
            return 0.0
        rank = q * self.n
        seen = 0
        for k in sorted(self.counts):
            seen += self.counts[k]
            if seen >= rank:
                return min(self.max_s, LOW_S * 10 ** ((k + 1) / BUCKETS_PER_DECADE))
        return self.max_s

    def to_json(self) -> dict[str, Any]:
        """Plain JSON (bucket keys as strings)."""
        return {"counts": {str(k): c for k, c in self.counts.items()}, "n": self.n,
                "max_s": self.max_s}

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> Histogram:
        """From :meth:`to_json`."""
        return cls({int(k): int(c) for k, c in obj.get("counts", {}).items()},
                   int(obj.get("n", 0)), float(obj.get("max_s", 0.0)))


class CycleTimer:
    """Times every call of ``obj.<name>`` (CPU and wall) by wrapping it on the instance.

    Args:
        obj: the object whose method is timed (e.g. the navigator).
        name: the method (e.g. ``step``).
        on_call: called with the clock time of each call (for :class:`RateWatch`), optional.
        now: the application clock's ``now`` (for ``on_call``).
    """

    def __init__(self, obj: Any, name: str, on_call: Callable[[float], None] | None = None,
                 now: Callable[[], float] | None = None) -> None:
        self.cpu = Histogram()
        self.wall = Histogram()
        self.calls = 0
        inner = getattr(obj, name)
        cpu, wall = self.cpu, self.wall

        def timed(*args: Any, **kwargs: Any) -> Any:
            c0, w0 = thread_cpu_time(), wall_perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                cpu.add(thread_cpu_time() - c0)
                wall.add(wall_perf_counter() - w0)
                self.calls += 1
                if on_call is not None and now is not None:
                    on_call(now())

        setattr(obj, name, timed)

    def take(self) -> dict[str, Any]:
        """The histograms since the last call (and start new ones)."""
        out = {"cpu": self.cpu.to_json(), "wall": self.wall.to_json(), "calls": self.calls}
        self.cpu.counts, self.cpu.n, self.cpu.max_s = {}, 0, 0.0
        self.wall.counts, self.wall.n, self.wall.max_s = {}, 0, 0.0
        self.calls = 0
        return out


class RateWatch:
    """Steps per simulated second and the longest gap between two steps (seconds).

    Args:
        rate_hz: the configured rate.
    """

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.last_s: float | None = None
        self.max_gap_s = 0.0
        self.gaps_over: int = 0
        self.steps = 0
        self.since_s: float | None = None
        self.excused: list[tuple[float, float]] = []
        self.excused_s = 0.0

    def excuse(self, start_s: float, end_s: float) -> None:
        """Gaps inside ``[start_s, end_s]`` (an injected stall) are counted apart."""
        self.excused.append((start_s, end_s))

    def on_step(self, t_s: float) -> None:
        """One step at clock time ``t_s``."""
        if self.since_s is None:
            self.since_s = t_s
        self.steps += 1
        if self.last_s is not None:
            gap = t_s - self.last_s
            excused = any(self.last_s <= b + 1e-6 and t_s >= a - 1e-6
                          for a, b in self.excused)  # the gap overlaps an injected stall
            if excused:  # the stall's time is not counted in the rate either
                self.excused_s += max(0.0, gap - 1.0 / self.rate_hz)
            else:
                self.max_gap_s = max(self.max_gap_s, gap)
                if gap > 2.0 / self.rate_hz + 1e-6:
                    self.gaps_over += 1
        self.last_s = t_s

    def take(self, now_s: float) -> dict[str, Any]:
        """Rate and gaps since the last call (then start over)."""
        span = now_s - self.since_s if self.since_s is not None else 0.0
        counted = span - self.excused_s
        out = {"steps": self.steps, "span_s": round(span, 3),
               "excused_s": round(self.excused_s, 3),
               "rate_hz": round(self.steps / counted, 3) if counted > 0 else None,
               "max_gap_s": round(self.max_gap_s, 4), "gaps_over": self.gaps_over}
        self.steps, self.since_s, self.max_gap_s, self.gaps_over = 0, now_s, 0.0, 0
        self.excused_s = 0.0
        self.excused = [(a, b) for a, b in self.excused if b + 1.0 >= now_s]
        return out


def _proc_status_threads() -> int:
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Threads:"):
                    return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return threading.active_count()


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * _PAGE / 1e6
    except (OSError, ValueError, IndexError):
        return float("nan")


def _fds() -> int:
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:
        return -1


def _web_queues(app: Any) -> dict[str, int]:
    web = getattr(app, "web", None)
    if web is None:
        return {"clients": 0, "reliable_max": 0, "streams_max": 0}
    clients = list(web.hub.clients)
    return {"clients": len(clients),
            "reliable_max": max((len(c.reliable) for c in clients), default=0),
            "streams_max": max((len(c.pending) for c in clients), default=0)}


def resources(app: Any) -> dict[str, Any]:
    """One sample of the process's resources and queues (see the module docstring)."""
    backlog = app.bus.backlog()
    worst = max(backlog.items(), key=lambda kv: kv[1], default=("", 0))
    recorder = getattr(app, "recorder", None)
    log = getattr(app, "eventlog", None)
    return {
        "rss_mb": round(_rss_mb(), 3), "fds": _fds(), "threads": _proc_status_threads(),
        "py_threads": threading.active_count(),
        "bus_backlog_max": worst[1], "bus_backlog_topic": worst[0],
        "bus_subscribers": sum(app.bus.stats()[t].subscribers for t in app.bus.stats()),
        "web": _web_queues(app),
        "recorder_queue": len(recorder.queue) if recorder is not None else 0,
        "eventlog_queue": log.pending() if log is not None else 0,
    }
