"""The transport the fleet code talks to, and an in-process one for tests and simulation.

The fleet parts (the rover's bridge, the traffic layer, the fleet manager) never touch Zenoh
directly: they use a :class:`Transport` — publish, subscribe, liveliness tokens, queryables
and queries. :class:`~curio.fleet.zenoh_link.ZenohTransport` is the real one;
:class:`MemoryTransport` connects transports of one process through a :class:`MemoryNetwork`
(deterministic, no sockets), so the fleet logic is tested without the ``curio[fleet]`` extra.

**Threads and the loop.** Incoming samples are *queued* (Zenoh calls back on its own
threads); :meth:`Transport.pump`, called from the event loop by the owner's part, hands them
to the handlers in a deterministic order: by sender, then the sender's sequence number. So a
handler always runs on the loop thread and never races the application. Queryable responders
are the exception: they run on the transport's thread and must only read immutable snapshots
(they never wait for the loop, so a query is answered even while the loop is busy).

**Never waiting on the network.** :meth:`Transport.put` returns at once (a full queue drops
the message and counts it); only :meth:`Transport.get` blocks, and the loop calls it through
``clock.offload`` (a worker thread on the real clock).

**Faults.** :meth:`Transport.cut` and :meth:`Transport.restore` simulate a lost and a regained
link (the tokens of a cut transport disappear for the others, nothing goes in or out).
"""

from __future__ import annotations

import hashlib
import threading
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, Protocol

from curio.fleet.keys import keyexpr_intersects

__all__ = [
    "InboxTransport",
    "MemoryNetwork",
    "MemoryTransport",
    "Responder",
    "Sample",
    "SampleHandler",
    "Transport",
    "TransportStats",
]


@dataclass(frozen=True, slots=True)
class Sample:
    """One message received: its key, payload and who sent it.

    Attributes:
        key: the concrete key it was published on.
        payload: the bytes.
        kind: ``put``; for liveliness ``put`` (a token appeared) or ``delete`` (it went).
        source: the sending transport's name ("" when unknown).
        seq: the sender's sequence number (orders the samples of one sender).
    """

    key: str
    payload: bytes
    kind: Literal["put", "delete"] = "put"
    source: str = ""
    seq: int = 0


SampleHandler = Callable[[Sample], None]
# A queryable's responder: (query key, parameters) -> [(reply key, payload), ...].
Responder = Callable[[str, str], list[tuple[str, bytes]]]


@dataclass
class TransportStats:
    """Traffic counters, per topic (the key's last chunk): messages and payload+key bytes.

    Attributes:
        out_msgs, out_bytes: what this transport sent.
        in_msgs, in_bytes: what its subscriptions received.
        dropped: puts dropped (a full send queue, or sent while cut or closed).
    """

    out_msgs: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    out_bytes: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    in_msgs: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    in_bytes: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    dropped: int = 0

    @staticmethod
    def topic_of(key: str) -> str:
        """The counter a key is counted under: its chunks after ``curio/<rover>/``."""
        parts = key.split("/")
        return "/".join(parts[2:]) if len(parts) > 2 else key

    def count_out(self, key: str, nbytes: int) -> None:
        """Count one message sent on ``key``."""
        topic = self.topic_of(key)
        self.out_msgs[topic] += 1
        self.out_bytes[topic] += nbytes + len(key)

    def count_in(self, key: str, nbytes: int) -> None:
        """Count one message received on ``key``."""
        topic = self.topic_of(key)
        self.in_msgs[topic] += 1
        self.in_bytes[topic] += nbytes + len(key)

    def totals(self) -> dict[str, int]:
        """Sums over topics: ``out_msgs``, ``out_bytes``, ``in_msgs``, ``in_bytes``."""
        return {"out_msgs": sum(self.out_msgs.values()), "out_bytes": sum(self.out_bytes.values()),
                "in_msgs": sum(self.in_msgs.values()), "in_bytes": sum(self.in_bytes.values())}


class Transport(Protocol):
    """What the fleet parts need from the network (see the module docstring)."""

    name: str
    stats: TransportStats

    def open(self) -> None:
        """Connect (declarations made before are made on the network now); once."""
        ...

    def close(self) -> None:
        """Disconnect for good."""
        ...

    @property
    def connected(self) -> bool:
        """Whether the link to the rest of the fleet is up."""
        ...

    def put(self, key: str, payload: bytes, *, express: bool = False,
            attachment: bytes | None = None) -> None:
        """Publish ``payload`` on ``key``; never blocks. ``attachment`` replaces the sender's
        own (ROS 2 publications carry ``rmw_zenoh``'s)."""
        ...

    def declare_cache(self, key: str, depth: int = 1) -> None:
        """Keep the last ``depth`` puts on ``key`` for subscribers that join later (ROS 2's
        transient-local durability)."""
        ...

    def subscribe(self, keyexpr: str, handler: SampleHandler) -> None:
        """Queue samples on keys matching ``keyexpr`` for ``handler`` (see :meth:`pump`)."""
        ...

    def watch_liveliness(self, keyexpr: str, handler: SampleHandler) -> None:
        """Queue token appearances (``put``) and disappearances (``delete``), present ones
        included."""
        ...

    def declare_token(self, key: str) -> None:
        """Hold the liveliness token ``key`` while connected."""
        ...

    def queryable(self, keyexpr: str, responder: Responder) -> None:
        """Answer queries matching ``keyexpr`` (the responder runs on the transport's thread)."""
        ...

    def get(self, selector: str, timeout_s: float = 2.0) -> list[Sample]:
        """Query every matching queryable; blocks up to ``timeout_s`` (call it off the loop)."""
        ...

    def pump(self) -> int:
        """Hand the queued samples to their handlers (loop thread); return how many."""
        ...

    def cut(self) -> None:
        """Simulate a lost link: nothing goes in or out, the tokens disappear for the others."""
        ...

    def restore(self) -> None:
        """Undo :meth:`cut`."""
        ...


@dataclass
class _Declared:
    keyexpr: str
    handler: SampleHandler
    liveliness: bool = False


class InboxTransport:
    """What both transports share: declarations kept for (re)connection, the inbox of received
    samples and their deterministic hand-over in :meth:`pump`, sequence numbers, counters.

    Args:
        name: this endpoint's name (a rover's name, ``manager``); it orders the samples.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.zid = ""
        self.stats = TransportStats()
        self._subs: list[_Declared] = []
        self._tokens: list[str] = []
        self._queryables: list[tuple[str, Responder]] = []
        self._inbox: list[tuple[tuple[str, int, str, str, int], SampleHandler, Sample]] = []
        self._lock = threading.Lock()
        self._seq = 0

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _enqueue(self, index: int, sample: Sample) -> None:
        """Queue ``sample`` for subscription ``index`` (any thread)."""
        sub = self._subs[index]
        order = (sample.source, sample.seq, sample.key, sample.kind, index)
        with self._lock:
            self._inbox.append((order, sub.handler, sample))
        if not sub.liveliness:
            self.stats.count_in(sample.key, len(sample.payload))

    def _before_pump(self) -> None:
        """Hook: wait until what was sent has arrived (the simulator's delivery ledger)."""

    def pump(self) -> int:
        """Hand the queued samples to their handlers, ordered by sender and sequence."""
        self._before_pump()
        with self._lock:
            batch, self._inbox = self._inbox, []
        batch.sort(key=lambda item: item[0])
        for _, handler, sample in batch:
            handler(sample)
        return len(batch)

    def pending(self) -> int:
        """Samples waiting for :meth:`pump`."""
        with self._lock:
            return len(self._inbox)


class MemoryNetwork:
    """Connects :class:`MemoryTransport` objects of one process (delivery is immediate)."""

    def __init__(self) -> None:
        self.transports: list[MemoryTransport] = []

    def up(self) -> list[MemoryTransport]:
        """The transports that are open and not cut."""
        return [t for t in self.transports if t.connected]

    def tokens(self) -> list[str]:
        """Every live token."""
        return [k for t in self.up() for k in t._tokens]

    def broadcast_token(self, key: str, kind: Literal["put", "delete"],
                        exclude: MemoryTransport | None = None) -> None:
        """Tell every liveliness watcher (but ``exclude``'s) that ``key`` appeared or went."""
        for t in self.up():
            if t is not exclude:
                t.tell(key, kind)


class MemoryTransport(InboxTransport):
    """An in-process transport on a :class:`MemoryNetwork` (see the module docstring)."""

    def __init__(self, name: str, network: MemoryNetwork) -> None:
        super().__init__(name)
        self.zid = hashlib.sha256(name.encode()).hexdigest()[:32]
        self.network = network
        self._open = False
        self._cut = False
        network.transports.append(self)

    @property
    def connected(self) -> bool:
        """Open and not cut."""
        return self._open and not self._cut

    def open(self) -> None:
        """Join the network: tokens appear, present tokens are reported to the watchers (a
        second call does nothing)."""
        if self._open:
            return
        self._open = True
        self._announce()

    def tell(self, key: str, kind: Literal["put", "delete"]) -> None:
        """Queue a token change for this transport's matching liveliness watchers."""
        for i, sub in enumerate(self._subs):
            if sub.liveliness and keyexpr_intersects(sub.keyexpr, key):
                self._enqueue(i, Sample(key, b"", kind, "~live", 0))

    def _announce(self) -> None:
        for key in self._tokens:
            self.network.broadcast_token(key, "put")
        for key in [k for t in self.network.up() if t is not self for k in t._tokens]:
            self.tell(key, "put")

    def close(self) -> None:
        """Leave the network for good."""
        if self.connected:
            self._withdraw()
        self._open = False

    def _withdraw(self) -> None:
        for key in self._tokens:
            self.network.broadcast_token(key, "delete", exclude=self)

    def cut(self) -> None:
        """Lose the link (tokens go for the others)."""
        if self.connected:
            self._withdraw()
        self._cut = True

    def restore(self) -> None:
        """Regain the link."""
        was_cut, self._cut = self._cut, False
        if was_cut and self._open:
            self._announce()

    def declare_cache(self, key: str, depth: int = 1) -> None:
        """Nothing to do in memory (no late joiners to serve)."""

    def put(self, key: str, payload: bytes, *, express: bool = False,
            attachment: bytes | None = None) -> None:
        """Deliver to every matching subscription of every connected transport."""
        if not self.connected:
            self.stats.dropped += 1
            return
        seq = self._next_seq()
        self.stats.count_out(key, len(payload))
        for t in self.network.up():
            for i, sub in enumerate(t._subs):
                if not sub.liveliness and keyexpr_intersects(sub.keyexpr, key):
                    t._enqueue(i, Sample(key, payload, "put", self.name, seq))

    def subscribe(self, keyexpr: str, handler: SampleHandler) -> None:
        """Queue matching samples for ``handler``."""
        self._subs.append(_Declared(keyexpr, handler))

    def watch_liveliness(self, keyexpr: str, handler: SampleHandler) -> None:
        """Queue token changes (present tokens included)."""
        self._subs.append(_Declared(keyexpr, handler, liveliness=True))
        if self.connected:
            index = len(self._subs) - 1
            for key in self.network.tokens():
                if keyexpr_intersects(keyexpr, key):
                    self._enqueue(index, Sample(key, b"", "put", "~live", 0))

    def declare_token(self, key: str) -> None:
        """Hold ``key`` while connected."""
        self._tokens.append(key)
        if self.connected:
            self.network.broadcast_token(key, "put")

    def queryable(self, keyexpr: str, responder: Responder) -> None:
        """Answer matching queries."""
        self._queryables.append((keyexpr, responder))

    def get(self, selector: str, timeout_s: float = 2.0) -> list[Sample]:
        """Ask every connected transport's matching queryables (at once)."""
        if not self.connected:
            return []
        key, _, params = selector.partition("?")
        out: list[Sample] = []
        for t in self.network.up():
            for keyexpr, responder in t._queryables:
                if keyexpr_intersects(keyexpr, key):
                    out.extend(Sample(k, p, "put", t.name) for k, p in responder(key, params))
        return out
