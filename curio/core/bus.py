"""The in-process message bus: typed topics, conflating streams, reliable commands.

* A :class:`Topic` is declared once (see ``curio/core/topics.py``) with its name, message type, kind
  and whether it is latched.
* ``stream`` topics conflate: each subscriber has a small ring (default one message); when it is
  full the oldest message is dropped and the drop counted. Sensors use streams.
* ``reliable`` topics never drop or merge messages: each subscriber's queue is unbounded.
  Commands and events use them (the original lost one-shot ROS messages).
* ``latched`` topics hand the last message to every new subscriber at once.
* :meth:`Bus.publish` never awaits and never runs subscriber code, so a slow subscriber can never
  stall a publisher. Driver threads use :meth:`Bus.publish_threadsafe`.
* A *tap* (:meth:`Bus.add_tap`) sees every message of every topic at the moment it is published,
  before any conflation: the flight recorder uses one. A tap is a plain function called inside
  ``publish``; it must be quick (queue the message and return), never raise and never publish.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any, Generic, Literal, TypeVar

T = TypeVar("T")

__all__ = ["Bus", "Subscription", "Tap", "Topic", "TopicStats"]


@dataclass(frozen=True, slots=True)
class Topic(Generic[T]):
    """A named channel for one message type.

    Attributes:
        name: ROS-style name, e.g. ``/scan``.
        type: the message class; ``publish`` rejects anything else.
        kind: ``stream`` (conflating) or ``reliable`` (never dropped).
        latched: new subscribers receive the last message.
        doc: one line saying who publishes it and what it means.
    """

    name: str
    type: type[T]
    kind: Literal["stream", "reliable"] = "stream"
    latched: bool = False
    doc: str = ""


@dataclass
class TopicStats:
    """Traffic counters of one topic."""

    published: int = 0
    dropped: int = 0
    subscribers: int = 0


class Subscription(Generic[T]):
    """A subscriber's queue. Iterate it with ``async for``, or poll with ``get_nowait``."""

    def __init__(self, bus: Bus, topic: Topic[T], maxsize: int | None) -> None:
        self.topic = topic
        self._bus = bus
        self._queue: deque[T] = deque(maxlen=maxsize)
        self._waiter: asyncio.Future[None] | None = None
        self.dropped = 0
        self.closed = False

    def _put(self, msg: T) -> bool:
        """Queue ``msg``; return True if an old message had to be dropped."""
        dropped = self._queue.maxlen is not None and len(self._queue) == self._queue.maxlen
        if dropped:
            self.dropped += 1
        self._queue.append(msg)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)
        return dropped

    def __len__(self) -> int:
        return len(self._queue)

    def get_nowait(self) -> T | None:
        """Return the oldest queued message, or None when the queue is empty."""
        return self._queue.popleft() if self._queue else None

    def drain(self) -> list[T]:
        """Return and remove every queued message, oldest first."""
        items = list(self._queue)
        self._queue.clear()
        return items

    async def get(self) -> T:
        """Wait for and return the next message."""
        while not self._queue:
            if self.closed:
                raise asyncio.CancelledError("subscription closed")
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None
        return self._queue.popleft()

    def __aiter__(self) -> AsyncIterator[T]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[T]:
        while not self.closed:
            yield await self.get()

    def close(self) -> None:
        """Stop receiving; a pending ``get`` is woken and ends the iteration."""
        if not self.closed:
            self.closed = True
            self._bus._unsubscribe(self)
            if self._waiter is not None and not self._waiter.done():
                self._waiter.set_result(None)


@dataclass
class _Channel:
    topic: Topic[Any]
    subscribers: list[Subscription[Any]] = field(default_factory=list)
    last: Any = None
    has_last: bool = False
    stats: TopicStats = field(default_factory=TopicStats)


Tap = Callable[[Topic[Any], Any], None]
"""A function that sees every published message: ``tap(topic, msg)`` (see :meth:`Bus.add_tap`)."""


class Bus:
    """Routes messages from publishers to subscribers inside one event loop.

    Args:
        topics: every topic the application may use; publishing or subscribing to an
            undeclared topic is an error (topics are declared once).
    """

    def __init__(self, topics: list[Topic[Any]] | None = None) -> None:
        self._channels: dict[str, _Channel] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._taps: list[Tap] = []
        for topic in topics or []:
            self.declare(topic)

    def declare(self, topic: Topic[T]) -> Topic[T]:
        """Declare ``topic``; declaring the same name with another type or kind is an error."""
        existing = self._channels.get(topic.name)
        if existing is not None:
            if existing.topic != topic:
                raise ValueError(f"topic {topic.name} already declared as {existing.topic}")
            return topic
        self._channels[topic.name] = _Channel(topic)
        return topic

    def topics(self) -> list[Topic[Any]]:
        """Every declared topic."""
        return [ch.topic for ch in self._channels.values()]

    def _channel(self, topic: Topic[Any]) -> _Channel:
        ch = self._channels.get(topic.name)
        if ch is None:
            raise KeyError(f"topic {topic.name} is not declared on this bus")
        return ch

    def bind_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        """Remember the loop that ``publish_threadsafe`` must hand messages to."""
        self._loop = loop

    def publish(self, topic: Topic[T], msg: T) -> None:
        """Deliver ``msg`` to every subscriber's queue; never blocks, never runs their code."""
        ch = self._channel(topic)
        if not isinstance(msg, topic.type):
            raise TypeError(
                f"{topic.name} carries {topic.type.__name__}, got {type(msg).__name__}"
            )
        ch.stats.published += 1
        ch.last = msg
        ch.has_last = True
        for tap in self._taps:
            tap(topic, msg)
        for sub in ch.subscribers:
            if sub._put(msg):
                ch.stats.dropped += 1

    def add_tap(self, tap: Tap) -> None:
        """Call ``tap(topic, msg)`` for every message published from now on, on any topic.

        The tap runs inside :meth:`publish`, on the loop: it must only queue the message (no
        I/O, no waiting), never raise and never publish.
        """
        self._taps.append(tap)

    def remove_tap(self, tap: Tap) -> None:
        """Stop calling ``tap`` (no error if it was not added)."""
        if tap in self._taps:
            self._taps.remove(tap)

    def publish_threadsafe(self, topic: Topic[T], msg: T) -> None:
        """Publish from another thread (device I/O threads)."""
        if self._loop is None:
            raise RuntimeError("bus.bind_loop() must be called before publish_threadsafe")
        self._loop.call_soon_threadsafe(self.publish, topic, msg)

    def subscribe(self, topic: Topic[T], maxsize: int | None = None) -> Subscription[T]:
        """Subscribe to ``topic``.

        Args:
            maxsize: ring size for a stream (default 1: only the latest message is kept).
                Reliable topics ignore it: their queues are unbounded.
        """
        ch = self._channel(topic)
        size: int | None = None if topic.kind == "reliable" else (maxsize or 1)
        sub: Subscription[T] = Subscription(self, topic, size)
        ch.subscribers.append(sub)
        ch.stats.subscribers = len(ch.subscribers)
        if topic.latched and ch.has_last:
            sub._put(ch.last)
        return sub

    def _unsubscribe(self, sub: Subscription[Any]) -> None:
        ch = self._channels.get(sub.topic.name)
        if ch is not None and sub in ch.subscribers:
            ch.subscribers.remove(sub)
            ch.stats.subscribers = len(ch.subscribers)

    def latest(self, topic: Topic[T]) -> T | None:
        """Return the last message published on ``topic`` (latched or not), or None."""
        ch = self._channel(topic)
        return ch.last if ch.has_last else None  # type: ignore[no-any-return]

    def stats(self) -> dict[str, TopicStats]:
        """Counters per topic name."""
        return {name: ch.stats for name, ch in self._channels.items()}

    def backlog(self) -> dict[str, int]:
        """The longest subscriber queue of each topic, in messages (a stream's ring is
        bounded; a reliable topic's queue grows while its subscriber does not drain it)."""
        return {name: max((len(s) for s in ch.subscribers), default=0)
                for name, ch in self._channels.items()}

    def total_dropped(self) -> int:
        """Messages dropped by conflation on all topics."""
        return sum(ch.stats.dropped for ch in self._channels.values())
