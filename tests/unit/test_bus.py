"""Bus semantics: conflation with counted drops, reliability, latching, slow subscribers."""

from __future__ import annotations

import asyncio

import pytest

from curio.core.bus import Bus, Topic
from curio.core.clock import SimClock
from curio.core.messages import Event, OperatorCommand, Twist
from curio.core.topics import ALL_TOPICS, EVENTS, OPERATOR, make_bus

STREAM = Topic("/test_stream", Twist)
LATCHED = Topic("/test_latched", Twist, latched=True)
RELIABLE = Topic("/test_reliable", Event, kind="reliable")


def make() -> Bus:
    return Bus([STREAM, LATCHED, RELIABLE])


def test_stream_conflates_and_counts_drops() -> None:
    bus = make()
    sub = bus.subscribe(STREAM)
    for i in range(5):
        bus.publish(STREAM, Twist(float(i), linear_mps=float(i)))
    assert len(sub) == 1
    msg = sub.get_nowait()
    assert msg is not None and msg.linear_mps == 4.0
    assert sub.dropped == 4
    assert bus.stats()["/test_stream"].dropped == 4
    assert bus.stats()["/test_stream"].published == 5


def test_stream_ring_keeps_the_newest_n() -> None:
    bus = make()
    sub = bus.subscribe(STREAM, maxsize=3)
    for i in range(5):
        bus.publish(STREAM, Twist(float(i)))
    assert [m.stamp for m in sub.drain()] == [2.0, 3.0, 4.0]


def test_reliable_never_drops_or_collapses() -> None:
    bus = make()
    sub = bus.subscribe(RELIABLE)
    for i in range(10_000):
        bus.publish(RELIABLE, Event(float(i), "same.kind"))
    got = sub.drain()
    assert len(got) == 10_000
    assert [e.stamp for e in got[:3]] == [0.0, 1.0, 2.0]
    assert bus.stats()["/test_reliable"].dropped == 0


def test_latched_topic_hands_last_value_to_new_subscribers() -> None:
    bus = make()
    bus.publish(LATCHED, Twist(1.0, 0.1))
    bus.publish(LATCHED, Twist(2.0, 0.2))
    late = bus.subscribe(LATCHED)
    msg = late.get_nowait()
    assert msg is not None and msg.stamp == 2.0
    unlatched = bus.subscribe(STREAM)
    bus_latest_before = bus.latest(STREAM)
    assert unlatched.get_nowait() is None and bus_latest_before is None


def test_publish_checks_the_message_type_and_declaration() -> None:
    bus = make()
    with pytest.raises(TypeError, match="carries Twist"):
        bus.publish(STREAM, Event(0.0, "x"))  # type: ignore[arg-type]
    with pytest.raises(KeyError, match="not declared"):
        bus.publish(Topic("/nope", Twist), Twist(0.0))
    with pytest.raises(ValueError, match="already declared"):
        bus.declare(Topic("/test_stream", Event))


async def test_slow_subscriber_never_stalls_the_publisher() -> None:
    bus = make()
    clock = SimClock()
    fast_seen: list[float] = []
    slow_seen: list[float] = []
    fast_sub, slow_sub = bus.subscribe(STREAM), bus.subscribe(STREAM)

    async def publisher() -> None:
        async for t in clock.every(0.01):
            bus.publish(STREAM, Twist(t))
            if t >= 1.0:
                return

    async def fast() -> None:
        async for msg in fast_sub:
            fast_seen.append(msg.stamp)

    async def slow() -> None:
        async for msg in slow_sub:
            slow_seen.append(msg.stamp)
            await clock.sleep(0.25)  # a slow consumer (e.g. a web client)

    pub = asyncio.create_task(publisher())
    tasks = [asyncio.create_task(fast()), asyncio.create_task(slow())]
    await clock.run(until_s=1.5)
    assert pub.done()  # the publisher finished on time: it was never blocked
    assert len(fast_seen) == 101
    assert 4 <= len(slow_seen) <= 7  # the slow one only ever sees the latest
    assert slow_sub.dropped > 90
    for t in tasks:
        t.cancel()


async def test_subscription_close_ends_iteration() -> None:
    bus = make()
    sub = bus.subscribe(RELIABLE)
    got: list[str] = []

    async def consume() -> None:
        async for ev in sub:
            got.append(ev.kind)

    task = asyncio.create_task(consume())
    bus.publish(RELIABLE, Event(0.0, "a"))
    await asyncio.sleep(0)  # noqa: TID251 - let the consumer run once
    await asyncio.sleep(0)  # noqa: TID251
    sub.close()
    with pytest.raises(asyncio.CancelledError):
        await asyncio.wait_for(task, 1.0)
    assert got == ["a"]
    bus.publish(RELIABLE, Event(1.0, "b"))
    assert bus.stats()["/test_reliable"].subscribers == 0


async def test_publish_threadsafe_lands_on_the_loop() -> None:
    bus = make_bus()
    bus.bind_loop(asyncio.get_running_loop())
    sub = bus.subscribe(EVENTS)
    await asyncio.to_thread(bus.publish_threadsafe, EVENTS, Event(1.0, "from.thread"))
    ev = await asyncio.wait_for(sub.get(), 1.0)
    assert ev.kind == "from.thread"


def test_application_topics_are_unique_and_commands_are_reliable() -> None:
    names = [t.name for t in ALL_TOPICS]
    assert len(names) == len(set(names))
    assert OPERATOR.kind == "reliable" and EVENTS.kind == "reliable"
    bus = make_bus()
    sub = bus.subscribe(OPERATOR)
    for _ in range(3):
        bus.publish(OPERATOR, OperatorCommand(0.0, "go_home"))
    assert len(sub.drain()) == 3  # identical one-shot commands are not collapsed
