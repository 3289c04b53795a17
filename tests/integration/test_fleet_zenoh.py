"""The Zenoh transport over the loopback: delivery, liveliness, queries, a cut link, and the
simulator's delivery ledger (what makes a fleet simulation reproducible)."""

from __future__ import annotations

import pytest

from curio.core.clock import wall_perf_counter
from curio.fleet.transport import Sample
from curio.fleet.zenoh_link import (
    DeliveryLedger,
    ZenohSettings,
    ZenohTransport,
    free_local_endpoint,
)

pytest.importorskip("zenoh")


@pytest.fixture
def net():
    ledger = DeliveryLedger(timeout_s=5.0)
    ep = free_local_endpoint()
    router = ZenohTransport("manager", ZenohSettings("router", listen=(ep,)), ledger=ledger)
    rovers = [ZenohTransport(n, ZenohSettings("client", connect=(ep,)), ledger=ledger)
              for n in ("r1", "r2")]
    yield ledger, router, rovers
    for t in (*rovers, router):
        t.close()


def test_samples_tokens_and_queries_cross_the_loopback(net) -> None:
    ledger, router, (r1, r2) = net
    got: list[Sample] = []
    live: list[tuple[str, str]] = []
    router.subscribe("curio/*/pose", got.append)
    router.watch_liveliness("curio/*/alive", lambda s: live.append((s.key, s.kind)))
    r2.queryable("curio/r2/q/*", lambda key, params: [("curio/r2/q/map", b"MAP")])
    for r in (r1, r2):
        r.declare_token(f"curio/{r.name}/alive")
    router.open()
    r1.open()
    r2.open()
    assert router.sync_routes([r1, r2])
    for i in range(20):
        r2.put("curio/r2/pose", b"b%d" % i)
        r1.put("curio/r1/pose", b"a%d" % i)
    router.pump()
    assert [s.payload for s in got] == [b"a%d" % i for i in range(20)] + [
        b"b%d" % i for i in range(20)]
    assert sorted(live) == [("curio/r1/alive", "put"), ("curio/r2/alive", "put")]
    assert [(s.key, s.payload) for s in r1.get("curio/*/q/map", 2.0)] == [
        ("curio/r2/q/map", b"MAP")]
    r1.cut()
    assert not r1.connected and r2.connected
    r1.put("curio/r1/pose", b"lost")
    router.pump()
    assert live[-1] == ("curio/r1/alive", "delete") and got[-1].payload == b"b19"
    r1.restore()
    assert router.sync_routes([r1, r2])
    r1.put("curio/r1/pose", b"back")
    router.pump()
    assert live[-1] == ("curio/r1/alive", "put") and got[-1].payload == b"back"
    assert ledger.timeouts == 0 and ledger.received == ledger.expected


def test_a_stuck_network_never_blocks_the_caller(monkeypatch) -> None:
    """With threaded puts (the rover on real time) a put returns at once even when Zenoh's
    own put hangs; beyond the bounded queue messages are dropped and counted."""
    import threading

    from curio.fleet import zenoh_link

    monkeypatch.setattr(zenoh_link, "SEND_QUEUE", 5)
    release = threading.Event()

    class Stuck:
        def put(self, *args, **kwargs) -> None:
            release.wait(5.0)

    t = ZenohTransport("r1", ZenohSettings(), threaded_puts=True)
    t._zenoh = pytest.importorskip("zenoh")
    t._s = zenoh_link._Session(Stuck())
    t._queue = zenoh_link.queue.Queue(zenoh_link.SEND_QUEUE)
    t._sender = threading.Thread(target=t._send_loop, daemon=True)
    t._sender.start()
    start = wall_perf_counter()
    for i in range(50):
        t.put("curio/r1/pose", b"%d" % i)
    elapsed = wall_perf_counter() - start
    release.set()
    assert elapsed < 4.0  # a blocking put would take the stuck put's 5 s
    assert t.stats.dropped >= 40 and t.stats.out_msgs["pose"] == 50
    t.close()
