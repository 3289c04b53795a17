"""The queue between the event loop and the recorder's writer thread.

Bounded twice — in messages and in (estimated) bytes — so a stalled disk can never grow it
until memory runs out. When it is full the oldest entries are dropped and counted, per bus
topic (``drop_oldest``, the policy on the real clock: the loop never waits). On a simulated
clock the recorder asks for ``wait`` instead: the loop waits for the writer to make room, which
stops simulated time meanwhile and so costs the simulation nothing, and the recording is
complete (a replay needs every message). A writer that has not started yet, or has died, is
never waited for.

Thread safety: one lock guards the deque and the counters; the loop (or any logging thread)
puts, the writer thread takes everything queued at once.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from curio.core import messages as m

__all__ = ["Entry", "RecordQueue", "estimate_size"]

WAIT_LIMIT_S = 10.0  # a writer that makes no room for this long is treated as stalled


@dataclass(slots=True)
class Entry:
    """One message waiting for the writer.

    Attributes:
        topic: the bus topic's name (or a pseudo-topic such as ``/log``).
        msg: the message (immutable: encoded later, on the writer thread).
        t_s: the clock's ``now()`` when it was published, seconds.
        seq: the publish order over all topics.
        size: estimated encoded size, bytes.
    """

    topic: str
    msg: Any
    t_s: float
    seq: int
    size: int


def estimate_size(msg: Any) -> int:
    """The approximate encoded size of a message in bytes (for the byte bound)."""
    if isinstance(msg, m.LaserScan):
        return 12 * len(msg.ranges_m) + 400
    if isinstance(msg, m.GridMessage):
        return int(np.size(msg.data) * 4 // 3) + 400
    if isinstance(msg, m.TreeSnapshot):
        return 150 * len(msg.nodes) + 400
    if isinstance(msg, m.Path):
        return 120 * len(msg.poses) + 200
    return 300


class RecordQueue:
    """A bounded FIFO of :class:`Entry`.

    Args:
        max_messages: most entries held.
        max_bytes: most estimated bytes held.
        when_full: ``drop_oldest`` or ``wait`` (see the module docstring).
    """

    def __init__(self, max_messages: int, max_bytes: int,
                 when_full: Literal["drop_oldest", "wait"] = "drop_oldest") -> None:
        self.max_messages = max_messages
        self.max_bytes = max_bytes
        self.when_full = when_full
        self._items: deque[Entry] = deque()
        self._bytes = 0
        self._lock = threading.Lock()
        self._ready = threading.Condition(self._lock)
        self._space = threading.Condition(self._lock)
        self._notify_at = max(1, max_messages // 4)
        self._closed = False
        self.consumer_alive = False
        self.dropped: Counter[str] = Counter()
        self.waits = 0
        self.high_water = 0

    def __len__(self) -> int:
        return len(self._items)

    @property
    def queued_bytes(self) -> int:
        """Estimated bytes waiting."""
        return self._bytes

    @property
    def dropped_total(self) -> int:
        """Entries dropped so far (all topics)."""
        return sum(self.dropped.values())

    def _full(self, size: int) -> bool:
        return bool(self._items) and (len(self._items) >= self.max_messages
                                      or self._bytes + size > self.max_bytes)

    def put(self, entry: Entry, *, may_wait: bool = True) -> None:
        """Queue ``entry``; when full, wait (policy ``wait``, if allowed) or drop the oldest."""
        with self._lock:
            if (self._full(entry.size) and may_wait and self.when_full == "wait"
                    and self.consumer_alive and not self._closed):
                self.waits += 1
                self._ready.notify()
                self._space.wait_for(lambda: not self._full(entry.size) or self._closed
                                     or not self.consumer_alive, WAIT_LIMIT_S)
            while self._full(entry.size):
                old = self._items.popleft()
                self._bytes -= old.size
                self.dropped[old.topic] += 1
            self._items.append(entry)
            self._bytes += entry.size
            self.high_water = max(self.high_water, len(self._items))
            if len(self._items) >= self._notify_at:
                self._ready.notify()

    def take(self, timeout_s: float) -> list[Entry]:
        """Everything queued, oldest first; waits up to ``timeout_s`` while it is empty."""
        with self._lock:
            if not self._items and not self._closed:
                self._ready.wait(timeout_s)
            items = list(self._items)
            self._items.clear()
            self._bytes = 0
            self._space.notify_all()
            return items

    def close(self) -> None:
        """Wake everyone: no more waiting (entries already queued can still be taken)."""
        with self._lock:
            self._closed = True
            self._ready.notify_all()
            self._space.notify_all()

    def consumer_started(self) -> None:
        """The writer runs: producers may wait for it (policy ``wait``)."""
        with self._lock:
            self.consumer_alive = True

    def consumer_died(self) -> None:
        """The writer is gone: producers must never wait for it again."""
        with self._lock:
            self.consumer_alive = False
            self._space.notify_all()
