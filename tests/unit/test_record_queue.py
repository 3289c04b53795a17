"""The recorder's queue: bounded in messages and bytes, drop-oldest with counted drops, or
the loop waiting for the writer on simulated time."""

from __future__ import annotations

import threading

from curio.core.clock import wall_perf_counter
from curio.record.queue import Entry, RecordQueue


def entry(topic: str, seq: int, size: int = 100) -> Entry:
    return Entry(topic, None, float(seq), seq, size)


def test_full_by_count_drops_the_oldest_and_counts_them_per_topic() -> None:
    q = RecordQueue(max_messages=3, max_bytes=10**9)
    for i in range(5):
        q.put(entry("/imu" if i < 2 else "/scan", i))
    assert [e.seq for e in q.take(0.0)] == [2, 3, 4]
    assert q.dropped == {"/imu": 2}
    assert q.dropped_total == 2 and q.high_water == 3


def test_full_by_bytes_drops_as_many_old_entries_as_needed() -> None:
    q = RecordQueue(max_messages=1000, max_bytes=1000)
    for i in range(4):
        q.put(entry("/scan", i, 300))
    q.put(entry("/map", 9, 700))  # needs room for 700 bytes: three scans go
    kept = q.take(0.0)
    assert [e.seq for e in kept] == [3, 9]
    assert q.dropped["/scan"] == 3 and q.queued_bytes == 0


def test_one_entry_bigger_than_the_bound_is_still_kept() -> None:
    q = RecordQueue(max_messages=10, max_bytes=100)
    q.put(entry("/map", 1, 5000))
    assert len(q) == 1 and q.dropped_total == 0


def test_wait_policy_blocks_the_producer_until_the_writer_takes() -> None:
    q = RecordQueue(max_messages=2, max_bytes=10**9, when_full="wait")
    q.consumer_started()
    q.put(entry("/a", 1))
    q.put(entry("/a", 2))
    producer = threading.Thread(target=q.put, args=(entry("/a", 3),))
    producer.start()  # the queue is full: it waits instead of dropping
    producer.join(0.3)
    assert producer.is_alive() and q.waits == 1
    start = wall_perf_counter()
    assert [e.seq for e in q.take(1.0)] == [1, 2]
    producer.join(5.0)
    assert not producer.is_alive() and wall_perf_counter() - start < 5.0
    assert q.dropped_total == 0 and [e.seq for e in q.take(0.0)] == [3]


def test_wait_policy_never_waits_for_a_writer_that_is_not_running() -> None:
    q = RecordQueue(max_messages=1, max_bytes=10**9, when_full="wait")
    q.put(entry("/a", 1))
    q.put(entry("/a", 2))  # not started: drops at once
    q.consumer_started()
    q.consumer_died()
    q.put(entry("/a", 3))  # died: drops at once
    assert q.dropped_total == 2 and q.waits == 0
    assert q.take(0.0)[0].seq == 3
