"""The flight recorder part: every bus message to the sinks, off the event loop.

* A **bus tap** (:meth:`curio.core.bus.Bus.add_tap`) sees each message when it is published —
  before any conflation — and queues it with the clock's ``now()`` and a global sequence
  number: a few microseconds on the loop, no encoding, no I/O.
* A **writer thread** takes everything queued every 50 ms, encodes it
  (:class:`~curio.record.codec.Codec`) and hands the payloads to the sinks: MCAP files
  (:class:`~curio.record.mcap_sink.McapSink`) and, optionally, the live Foxglove server. It
  flushes the sinks every ``record.flush_s`` of wall time, and also whenever the data it wrote
  spans ``record.flush_s`` of clock time (a simulation runs faster than the wall clock: its
  files are then cut into the same chunks as a real run's).
* The **queue** (:class:`~curio.record.queue.RecordQueue`) is bounded in messages and bytes and
  drops its oldest entries (counted per topic) when full; on a simulated clock the loop waits for
  the writer instead, so scenario recordings are complete.
* Costmaps are big and change often: ``/costmap`` and ``/local_costmap`` are recorded at most
  at ``record.costmap_rate_hz`` and ``record.local_costmap_rate_hz``, and only when their
  ``version`` changed (the others are counted as ``skipped``).
* Python log records of the ``curio`` loggers go to ``/log``; the fixed frames and the scene
  (footprint, waypoints) are written first.

Times: MCAP ``log_time`` is the clock's ``now()`` plus ``time_offset_s`` (wall-clock
nanoseconds, what Foxglove shows); ``publish_time`` is ``now()`` itself in nanoseconds, which a
replay uses to publish each message at the very time it was published. ``sequence`` is the
publish order (the low 32 bits).

Health: ``/health`` name ``recorder`` every second with ``messages``, ``dropped``, ``skipped``,
``queued``, ``queue_high_water``, ``bytes_written``, ``files``, ``write_errors``,
``encode_errors``, ``lost_while_failing`` (messages not recorded while a sink failed) and
``writer_cpu_s``. ``degraded`` while a sink rests after a failed write (the disk is full) and
for ``HEALTH_MEMORY_S`` after the last failure or drop; ``ok`` again afterwards.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Sequence
from typing import Any, Protocol

from curio.core.bus import Bus, Topic
from curio.core.clock import Clock, thread_cpu_time, wall_perf_counter
from curio.core.messages import DriverHealth
from curio.core.topics import HEALTH
from curio.record.codec import ChannelSpec, Codec, Encoded, to_ns
from curio.record.queue import Entry, RecordQueue, estimate_size

__all__ = ["Recorder", "Sink"]

log = logging.getLogger("curio.record")

PRE_ENCODED = ""  # Entry.topic of payloads encoded up front (the fixed frames, the scene)
LOG_TOPIC = "/log"
TAKE_PERIOD_S = 0.05
RETRY_S = 5.0
HEALTH_MEMORY_S = 10.0  # health stays degraded this long after the last failure (clock s)


class Sink(Protocol):
    """Where the writer thread puts encoded messages (MCAP files, a live server)."""

    def write(self, spec: ChannelSpec, log_ns: int, publish_ns: int, seq: int,
              data: bytes) -> None:
        """Take one message; raise OSError when it cannot."""
        ...

    def flush(self) -> None:
        """Make what was written durable / sent."""
        ...

    def close(self) -> None:
        """Finish (called once, on the writer thread)."""
        ...

    def describe(self) -> dict[str, Any]:
        """Counters for health (numbers)."""
        ...


class _LogHandler(logging.Handler):
    """Queues the ``curio`` loggers' records for ``/log`` (never waits, never raises)."""

    def __init__(self, recorder: Recorder, level: int) -> None:
        super().__init__(level)
        self.recorder = recorder

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.exc_info and record.exc_info[1] is not None:
                text += f" ({type(record.exc_info[1]).__name__}: {record.exc_info[1]})"
            self.recorder.queue_log(record.levelno, text, record.name, record.pathname,
                                    record.lineno)
        except Exception:  # pragma: no cover - logging must never fail the caller
            self.handleError(record)


class Recorder:
    """The recorder part (see the module docstring).

    Args:
        codec: encodes messages; its ``time_offset_s`` turns ``now()`` into wall time.
        sinks: where payloads go (opened lazily by their first write).
        queue: the bounded queue in front of the writer thread.
        flush_s: how often the sinks are flushed (wall seconds).
        grid_periods_s: bus topic → its shortest recording period (the costmaps), seconds.
        exclude: bus topics not recorded.
        log_level: Python records at or above it go to ``/log``; None: no log records.
        statics: payloads written first (the fixed frames, the scene).
    """

    def __init__(self, bus: Bus, clock: Clock, codec: Codec, sinks: Sequence[Sink], *,
                 queue: RecordQueue, flush_s: float = 1.0,
                 grid_periods_s: dict[str, float] | None = None,
                 exclude: frozenset[str] = frozenset(), log_level: int | None = logging.INFO,
                 statics: list[Encoded] | None = None) -> None:
        self.bus = bus
        self.clock = clock
        self.codec = codec
        self.sinks = list(sinks)
        self.queue = queue
        self.flush_s = flush_s
        self.grid_periods_s = dict(grid_periods_s or {})
        self.exclude = exclude
        self.seen: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()
        self.written: Counter[str] = Counter()
        self.write_errors = 0
        self.encode_errors = 0
        self.writer_cpu_s = 0.0
        self.error: str | None = None
        self._seq = 0
        self._last_grid: dict[str, tuple[float, int]] = {}
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._broken_until: dict[int, float] = {}
        self.retry_s = RETRY_S
        self.lost_while_failing = 0
        self._trouble_seen: tuple[int, int, int] = (0, 0, 0)
        self._trouble_at: float | None = None
        self._last_write_error: tuple[str, int] | None = None
        self._trouble_kind = "write"
        self._handler = _LogHandler(self, log_level) if log_level is not None else None
        if statics:
            self._put(PRE_ENCODED, statics, 0)
        bus.add_tap(self._tap)

    # --- on the loop (and logging threads) --------------------------------------------------
    def _put(self, topic: str, msg: Any, size: int, *, may_wait: bool = True) -> None:
        self._seq += 1
        self.queue.put(Entry(topic, msg, self.clock.now(), self._seq, size), may_wait=may_wait)

    def _tap(self, topic: Topic[Any], msg: Any) -> None:
        name = topic.name
        if name in self.exclude:
            return
        self.seen[name] += 1
        period = self.grid_periods_s.get(name)
        if period is not None:
            now = self.clock.now()
            last = self._last_grid.get(name)
            if last is not None and (now - last[0] < period or msg.version == last[1]):
                self.skipped[name] += 1
                return
            self._last_grid[name] = (now, msg.version)
        self._put(name, msg, estimate_size(msg))

    def queue_log(self, levelno: int, message: str, name: str, file: str, line: int) -> None:
        """Queue one log record for ``/log`` (any thread; never waits)."""
        if not self._stopping:
            self._put(LOG_TOPIC, (levelno, message, name, file, line), 200 + len(message),
                      may_wait=False)

    # --- the part ---------------------------------------------------------------------------
    async def run(self) -> None:
        """Start the writer thread, then publish health every second."""
        self.start_writer()
        async for t in self.clock.every(1.0, phase_s=0.007):
            self.bus.publish(HEALTH, self.health(t))

    def start_writer(self) -> None:
        """Start the writer thread and the log handler (once)."""
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._writer_main, name="curio-recorder",
                                        daemon=True)
        self.queue.consumer_started()
        self._thread.start()
        if self._handler is not None:
            logging.getLogger("curio").addHandler(self._handler)

    async def close(self) -> None:
        """Stop recording: write what is queued, finish every file."""
        self.bus.remove_tap(self._tap)
        if self._handler is not None:
            logging.getLogger("curio").removeHandler(self._handler)
        self._stopping = True
        self.queue.close()
        if self._thread is not None:
            await self.clock.offload(self._thread.join, 30.0)

    def health(self, stamp: float) -> DriverHealth:
        """The recorder's health and counters."""
        counters: dict[str, float] = {
            "messages": float(sum(self.written.values())),
            "dropped": float(self.queue.dropped_total),
            "skipped": float(sum(self.skipped.values())),
            "queued": float(len(self.queue)),
            "queue_high_water": float(self.queue.high_water),
            "write_errors": float(self.write_errors),
            "encode_errors": float(self.encode_errors),
            "writer_cpu_s": round(self.writer_cpu_s, 3),
        }
        for sink in self.sinks:
            counters.update({k: float(v) for k, v in sink.describe().items()})
        counters["lost_while_failing"] = float(self.lost_while_failing)
        if self.error is not None:
            return DriverHealth(stamp, "recorder", "error", self.error, counters)
        dropped = self.queue.dropped_total
        trouble = (self.write_errors, dropped, self.lost_while_failing)
        if trouble != self._trouble_seen:
            drops_only = trouble[0] == self._trouble_seen[0] and trouble[2] == \
                self._trouble_seen[2]
            self._trouble_kind = "drop" if drops_only else "write"
            self._trouble_seen, self._trouble_at = trouble, stamp
        resting = any(until > wall_perf_counter() for until in self._broken_until.values())
        recent = self._trouble_at is not None and stamp - self._trouble_at < HEALTH_MEMORY_S
        if resting or recent:
            if resting or self._trouble_kind == "write":
                last = self._last_write_error[0] if self._last_write_error else "?"
                msg = (f"writing failed ({last}); retrying every {self.retry_s:g} s; "
                       f"{self.lost_while_failing} messages not recorded so far: check the disk "
                       "(space, permissions)")
            else:
                msg = ("messages were dropped: the disk is too slow or the queue too small "
                       "(record.queue_messages, record.queue_mb)")
            return DriverHealth(stamp, "recorder", "degraded", msg, counters)
        return DriverHealth(stamp, "recorder", "ok", "", counters)

    # --- the writer thread --------------------------------------------------------------------
    def _writer_main(self) -> None:
        last_flush = wall_perf_counter()
        flushed_to: float | None = None  # the data time of the last flush
        try:
            while True:
                batch = self.queue.take(min(TAKE_PERIOD_S, self.flush_s))
                for entry in batch:
                    if flushed_to is None:
                        flushed_to = entry.t_s
                    elif entry.t_s - flushed_to >= self.flush_s:  # simulated time runs fast
                        self._each_sink(lambda s: s.flush())
                        flushed_to = entry.t_s
                    self._write_entry(entry)
                now = wall_perf_counter()
                if now - last_flush >= self.flush_s or (self._stopping and not batch):
                    self._each_sink(lambda s: s.flush())
                    last_flush = now
                    flushed_to = None
                self.writer_cpu_s = thread_cpu_time()
                if self._stopping and not batch and not len(self.queue):
                    break
        except Exception as exc:  # a bug: say so on /health, never take the rover down
            log.exception("the recorder's writer stopped")
            self.error = f"the writer stopped: {type(exc).__name__}: {exc}"
        finally:
            self.queue.consumer_died()
            for sink in self.sinks:
                try:
                    sink.close()
                except Exception:
                    log.exception("closing a recording sink failed")

    def _write_entry(self, entry: Entry) -> None:
        try:
            if entry.topic == PRE_ENCODED:
                encoded: list[Encoded] = entry.msg
            elif entry.topic == LOG_TOPIC:
                encoded = [self.codec.log(entry.t_s, *entry.msg)]
            else:
                encoded = self.codec.encode(entry.topic, entry.msg)
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            self.encode_errors += 1
            if self.encode_errors <= 5:
                log.error("cannot record a %s message: %s", entry.topic, exc)
            return
        if entry.topic not in (PRE_ENCODED, LOG_TOPIC):
            self.written[entry.topic] += 1
        log_ns = to_ns(entry.t_s + self.codec.time_offset_s)
        pub_ns = to_ns(entry.t_s)
        for spec, data in encoded:
            self._each_sink(lambda s, sp=spec, d=data: s.write(sp, log_ns, pub_ns, entry.seq, d),
                            counted=True)

    def _each_sink(self, action: Any, counted: bool = False) -> None:
        """Apply ``action`` to every working sink; a sink that fails rests ``retry_s`` (wall
        seconds); a message it misses meanwhile is counted (``counted``) as not recorded."""
        now = wall_perf_counter()
        for i, sink in enumerate(self.sinks):
            if self._broken_until.get(i, 0.0) > now:
                self.lost_while_failing += counted
                continue
            try:
                action(sink)
            except OSError as exc:
                self.write_errors += 1
                self.lost_while_failing += counted
                self._last_write_error = (str(exc), self.write_errors)
                self._broken_until[i] = now + self.retry_s
                log.error("recording failed (%s); retrying in %.0f s", exc, self.retry_s)
                abandon = getattr(sink, "abandon", None)
                if abandon is not None:
                    abandon()
