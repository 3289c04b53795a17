"""The Zenoh transport (``curio[fleet]``): :class:`ZenohTransport` and the simulator's
:class:`DeliveryLedger`.

``zenoh`` is imported when a transport opens, never at import time: without the extra Curio
runs as before and only ``fleet.enabled = true`` asks for it (a :class:`FleetSetupError` then
says how to install it).

A session is opened with the settings of :class:`ZenohSettings` (mode ``peer``, ``client`` or
``router``; endpoints to connect to and listen on; multicast scouting; or a Zenoh JSON5 config
file, which wins). Samples arrive on Zenoh's threads and wait in the inbox until
:meth:`~curio.fleet.transport.InboxTransport.pump` hands them to the loop. Every put carries a
small attachment ``<sender>:<seq>`` that orders the samples of one sender.

**Puts never block.** With ``threaded_puts`` (the rover on the real clock) a put goes into a
bounded queue that one sender thread empties; when it is full the message is dropped and
counted. Zenoh's own congestion control is ``DROP`` for every put.

**Deterministic simulation.** When several transports of one process run on a simulated clock
(``curio fleet sim``) a :class:`DeliveryLedger` counts, for every put, how many subscriptions of
the process will receive it (and every token change, how many liveliness watchers), and
``pump`` first waits (on the wall clock, briefly) until everything sent so far has arrived.
What a handler sees at a given simulated time then depends only on what was sent before, not
on thread timing; samples of one pump are ordered by sender and sequence.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import threading
from dataclasses import dataclass, field
from typing import Any, Literal

from curio.core.clock import wall_perf_counter, wall_sleep
from curio.core.errors import SetupError
from curio.fleet.keys import keyexpr_intersects
from curio.fleet.transport import InboxTransport, Responder, Sample, SampleHandler, _Declared

__all__ = [
    "DeliveryLedger",
    "FleetSetupError",
    "ZenohSettings",
    "ZenohTransport",
    "free_local_endpoint",
    "load_zenoh",
]

log = logging.getLogger("curio.fleet.zenoh")

SEND_QUEUE = 2000
PROBE_KEY = "curio/@sim/probe"


class FleetSetupError(SetupError):
    """The fleet cannot start: the extra is missing, a bad endpoint, a bad Zenoh config."""


def load_zenoh() -> Any:
    """Import ``zenoh`` (the ``curio[fleet]`` extra).

    Raises:
        FleetSetupError: it is not installed (the message says how to install it).
    """
    try:
        import zenoh
    except ImportError:
        raise FleetSetupError(
            "the fleet needs Eclipse Zenoh: pip install 'curio[fleet]' (eclipse-zenoh 1.x, "
            "wheels for x86-64 and aarch64), or set fleet.enabled = false") from None
    return zenoh


@dataclass(frozen=True)
class ZenohSettings:
    """How to open a session.

    Attributes:
        mode: ``peer`` (rovers, as ``rmw_zenoh`` does), ``client`` or ``router``.
        connect: endpoints to connect to, e.g. ``tcp/10.0.0.2:7447`` (a site's ``zenohd``).
        listen: endpoints to listen on.
        multicast_scouting: find peers by UDP multicast (off: endpoints only).
        config_file: a Zenoh JSON5 config used instead of the keys above ("" = none).
    """

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast_scouting: bool = False
    config_file: str = ""


def _zenoh_config(zenoh: Any, s: ZenohSettings) -> Any:
    if s.config_file:
        try:
            return zenoh.Config.from_file(s.config_file)
        except Exception as exc:
            raise FleetSetupError(f"fleet.zenoh_config {s.config_file}: cannot use this Zenoh "
                                  f"config ({exc})") from None
    conf = zenoh.Config()
    try:
        conf.insert_json5("mode", json.dumps(s.mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(s.multicast_scouting))
        if s.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(s.connect)))
        if s.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(s.listen)))
    except Exception as exc:
        raise FleetSetupError(f"fleet: bad Zenoh setting ({exc}); endpoints look like "
                              "tcp/192.168.1.10:7447") from None
    return conf


class DeliveryLedger:
    """Counts deliveries the transports of one process owe each other (see the module
    docstring); shared by every :class:`ZenohTransport` of a simulation.

    Args:
        timeout_s: how long :meth:`wait` waits on the wall clock before giving up (counted in
            :attr:`timeouts`: the run may then not be exactly reproducible).
    """

    def __init__(self, timeout_s: float = 2.0) -> None:
        self.timeout_s = timeout_s
        self._cond = threading.Condition()
        self.expected = 0
        self.received = 0
        self.timeouts = 0
        self._subs: list[tuple[str, str]] = []
        self._live: list[tuple[str, str]] = []
        self._tokens: dict[str, str] = {}
        self._active: set[str] = set()

    def activate(self, owner: str, active: bool) -> None:
        """``owner``'s session is up (True) or gone (False)."""
        with self._cond:
            (self._active.add if active else self._active.discard)(owner)

    def subscribed(self, owner: str, keyexpr: str) -> None:
        """A data subscription of ``owner`` exists (counted for later puts)."""
        with self._cond:
            self._subs.append((owner, keyexpr))

    def watching(self, owner: str, keyexpr: str) -> None:
        """A liveliness watcher of ``owner`` was declared: it is owed the present tokens."""
        with self._cond:
            self._live.append((owner, keyexpr))
            self.expected += sum(1 for k, o in self._tokens.items()
                                 if o in self._active and keyexpr_intersects(keyexpr, k))

    def put(self, key: str) -> None:
        """A put on ``key``: one delivery per matching subscription of an active owner."""
        with self._cond:
            self.expected += sum(1 for owner, expr in self._subs
                                 if owner in self._active and keyexpr_intersects(expr, key))

    def token(self, owner: str, key: str, alive: bool) -> None:
        """``owner``'s token ``key`` appeared or went: one event per matching watcher."""
        with self._cond:
            if alive:
                self._tokens[key] = owner
            else:
                self._tokens.pop(key, None)
            self.expected += sum(1 for o, expr in self._live
                                 if o in self._active and (alive or o != owner)
                                 and keyexpr_intersects(expr, key))

    def forget(self, owner: str) -> None:
        """``owner``'s declarations are gone with its session (they are made again)."""
        with self._cond:
            self._subs = [s for s in self._subs if s[0] != owner]
            self._live = [s for s in self._live if s[0] != owner]

    def arrived(self) -> None:
        """One delivery arrived."""
        with self._cond:
            self.received += 1
            self._cond.notify_all()

    def wait(self) -> bool:
        """Block until every owed delivery arrived; False (and counted) after the timeout."""
        deadline = wall_perf_counter() + self.timeout_s
        with self._cond:
            while self.received < self.expected:
                left = deadline - wall_perf_counter()
                if left <= 0.0:
                    self.timeouts += 1
                    log.warning("fleet sim: %d deliveries missing after %.1f s (a sample was "
                                "lost or a route was not ready)", self.expected - self.received,
                                self.timeout_s)
                    self.received = self.expected
                    return False
                self._cond.wait(left)
        return True


@dataclass
class _Session:
    """An open Zenoh session and what was declared on it."""

    session: Any
    handles: list[Any] = field(default_factory=list)
    cached: dict[str, Any] = field(default_factory=dict)


class ZenohTransport(InboxTransport):
    """A :class:`~curio.fleet.transport.Transport` over one Zenoh session.

    Args:
        name: this endpoint's name (orders its samples at the receivers).
        settings: how to open the session.
        ledger: the simulator's delivery ledger (None on the real clock).
        threaded_puts: send from a thread with a bounded queue (the rover on real time).
    """

    def __init__(self, name: str, settings: ZenohSettings, *,
                 ledger: DeliveryLedger | None = None, threaded_puts: bool = False) -> None:
        super().__init__(name)
        self.settings = settings
        self.ledger = ledger
        self._zenoh: Any = None
        self._s: _Session | None = None
        self._closing = False
        self._queue: queue.Queue[tuple[str, bytes, bytes, bool]] | None = None
        self._sender: threading.Thread | None = None
        self.threaded_puts = threaded_puts
        self._cached: dict[str, int] = {}

    # --- the session ----------------------------------------------------------------------

    def open(self) -> None:
        """Open the session and make every declaration on it (nothing when it is open).

        Raises:
            FleetSetupError: no ``zenoh`` module, or a config Zenoh refuses.
        """
        if self._s is not None:
            return
        zenoh = self._zenoh = load_zenoh()
        conf = _zenoh_config(zenoh, self.settings)
        try:
            session = zenoh.open(conf)
        except Exception as exc:
            raise FleetSetupError(f"fleet: cannot open a Zenoh session ({exc}); check "
                                  "fleet.connect and fleet.listen") from None
        self._s = _Session(session)
        self.zid = str(session.zid())
        if self.ledger is not None:
            self.ledger.activate(self.name, True)
        for index, sub in enumerate(self._subs):
            self._declare_sub(index, sub)
        for keyexpr, responder in self._queryables:
            self._declare_queryable(keyexpr, responder)
        for key in self._tokens:
            self._declare_token(key)
        for key, depth in self._cached.items():
            self._declare_cache(key, depth)
        if self.threaded_puts and self._sender is None:
            self._queue = queue.Queue(SEND_QUEUE)
            self._sender = threading.Thread(target=self._send_loop, name=f"zenoh-{self.name}",
                                            daemon=True)
            self._sender.start()

    @property
    def session(self) -> Any:
        """The Zenoh session (None when closed or cut)."""
        return self._s.session if self._s is not None else None

    @property
    def connected(self) -> bool:
        """The session is open and (unless it is the router) sees a router or a peer."""
        s = self._s
        if s is None:
            return False
        if self.settings.mode == "router":
            return True
        try:
            info = s.session.info
            return bool(info.routers_zid()) or bool(info.peers_zid())
        except Exception:
            return False

    def _drop_session(self) -> None:
        s, self._s = self._s, None
        if s is None:
            return
        if self.ledger is not None:
            self.ledger.wait()
            for key in self._tokens:
                self.ledger.token(self.name, key, False)
            self.ledger.activate(self.name, False)
            self.ledger.forget(self.name)
        with contextlib.suppress(Exception):
            s.session.close()

    def close(self) -> None:
        """Close the session and stop the sender thread."""
        self._closing = True
        if self._queue is not None:
            with contextlib.suppress(queue.Full):
                self._queue.put_nowait(("", b"", b"", False))
        self._drop_session()

    def cut(self) -> None:
        """Simulate a lost link: close the session (tokens vanish for the others)."""
        self._drop_session()

    def restore(self) -> None:
        """Reopen the session after :meth:`cut` (every declaration is made again)."""
        if self._s is None and not self._closing:
            self.open()

    # --- declarations ---------------------------------------------------------------------

    def subscribe(self, keyexpr: str, handler: SampleHandler) -> None:
        """Queue samples on keys matching ``keyexpr`` for ``handler``."""
        self._subs.append(_Declared(keyexpr, handler))
        if self._s is not None:
            self._declare_sub(len(self._subs) - 1, self._subs[-1])

    def watch_liveliness(self, keyexpr: str, handler: SampleHandler) -> None:
        """Queue token changes matching ``keyexpr`` (present tokens included)."""
        self._subs.append(_Declared(keyexpr, handler, liveliness=True))
        if self._s is not None:
            self._declare_sub(len(self._subs) - 1, self._subs[-1])

    def _declare_sub(self, index: int, sub: _Declared) -> None:
        assert self._s is not None
        zenoh = self._zenoh
        ledger = self.ledger
        name = self.name

        def on_sample(zs: Any) -> None:
            self._enqueue(index, _sample_of(zs, zenoh))
            if ledger is not None:
                ledger.arrived()

        if sub.liveliness:
            if ledger is not None:
                ledger.watching(name, sub.keyexpr)
            handle = self._s.session.liveliness().declare_subscriber(sub.keyexpr, on_sample,
                                                                     history=True)
        else:
            if ledger is not None:
                ledger.subscribed(name, sub.keyexpr)
            handle = self._s.session.declare_subscriber(sub.keyexpr, on_sample)
        self._s.handles.append(handle)

    def declare_token(self, key: str) -> None:
        """Hold the liveliness token ``key`` while the session is up."""
        self._tokens.append(key)
        if self._s is not None:
            self._declare_token(key)

    def _declare_token(self, key: str) -> None:
        assert self._s is not None
        if self.ledger is not None:
            self.ledger.token(self.name, key, True)
        self._s.handles.append(self._s.session.liveliness().declare_token(key))

    def queryable(self, keyexpr: str, responder: Responder) -> None:
        """Answer queries on ``keyexpr`` from Zenoh's thread with ``responder``'s replies."""
        self._queryables.append((keyexpr, responder))
        if self._s is not None:
            self._declare_queryable(keyexpr, responder)

    def _declare_queryable(self, keyexpr: str, responder: Responder) -> None:
        assert self._s is not None

        def on_query(query: Any) -> None:
            try:
                replies = responder(str(query.key_expr), str(query.parameters))
                for key, payload in replies:
                    query.reply(key, payload)
            except Exception:
                log.exception("fleet: the queryable %s failed", keyexpr)

        self._s.handles.append(self._s.session.declare_queryable(keyexpr, on_query))

    # --- traffic --------------------------------------------------------------------------

    def declare_cache(self, key: str, depth: int = 1) -> None:
        """Put ``key`` through an advanced publisher with a cache of ``depth`` samples and
        publisher detection (what ``rmw_zenoh`` does for transient-local publishers)."""
        self._cached[key] = depth
        if self._s is not None:
            self._declare_cache(key, depth)

    def _declare_cache(self, key: str, depth: int) -> None:
        assert self._s is not None
        import zenoh.ext as ext

        pub = ext.declare_advanced_publisher(self._s.session, key,
                                             cache=ext.CacheConfig(max_samples=depth),
                                             publisher_detection=True)
        self._s.handles.append(pub)
        self._s.cached[key] = pub

    def put(self, key: str, payload: bytes, *, express: bool = False,
            attachment: bytes | None = None) -> None:
        """Publish without ever blocking (dropped and counted when it cannot go)."""
        s = self._s
        if s is None:
            self.stats.dropped += 1
            return
        seq = self._next_seq()
        attachment = attachment if attachment is not None else f"{self.name}:{seq}".encode()
        self.stats.count_out(key, len(payload))
        if self.ledger is not None:
            self.ledger.put(key)
        if self._queue is not None:
            try:
                self._queue.put_nowait((key, payload, attachment, express))
            except queue.Full:
                self.stats.dropped += 1
            return
        self._put_now(s, key, payload, attachment, express)

    def _put_now(self, s: _Session, key: str, payload: bytes, attachment: bytes,
                 express: bool) -> None:
        try:
            cached = s.cached.get(key)
            if cached is not None:
                cached.put(payload, attachment=attachment)
                return
            s.session.put(key, payload, attachment=attachment, express=express,
                          congestion_control=self._zenoh.CongestionControl.DROP)
        except Exception as exc:  # a session closed meanwhile
            self.stats.dropped += 1
            log.debug("fleet: put on %s failed: %s", key, exc)

    def _send_loop(self) -> None:
        assert self._queue is not None
        while True:
            key, payload, attachment, express = self._queue.get()
            if self._closing:
                return
            s = self._s
            if s is None:
                self.stats.dropped += 1
                continue
            self._put_now(s, key, payload, attachment, express)

    def get(self, selector: str, timeout_s: float = 2.0) -> list[Sample]:
        """Query and wait (up to ``timeout_s``) for every reply; [] when not connected."""
        s = self._s
        if s is None:
            return []
        out = []
        try:
            for reply in s.session.get(selector, timeout=timeout_s):
                ok = reply.ok
                if ok is not None:
                    out.append(Sample(str(ok.key_expr), ok.payload.to_bytes()))
        except Exception as exc:
            log.debug("fleet: query %s failed: %s", selector, exc)
        return out

    def _before_pump(self) -> None:
        if self.ledger is not None:
            self.ledger.wait()

    def sync_routes(self, others: list[ZenohTransport], timeout_s: float = 10.0) -> bool:
        """Simulation start: exchange probes until every transport hears every other one, so
        that the declarations made before are known along every route (Zenoh propagates a
        session's declarations in order). Returns False after ``timeout_s``."""
        everyone = [self, *others]
        heard: dict[str, set[str]] = {t.name: set() for t in everyone}
        lock = threading.Lock()
        handles = []
        for t in everyone:
            assert t._s is not None

            def on_probe(zs: Any, me: str = t.name) -> None:
                with lock:
                    heard[me].add(str(zs.key_expr).rsplit("/", 1)[-1])

            handles.append(t._s.session.declare_subscriber(f"{PROBE_KEY}/*", on_probe))
        deadline = wall_perf_counter() + timeout_s
        names = {t.name for t in everyone}
        ok = False
        while wall_perf_counter() < deadline:
            for t in everyone:
                assert t._s is not None
                t._s.session.put(f"{PROBE_KEY}/{t.name}", b"")
            wall_sleep(0.02)
            with lock:
                if all(heard[n] >= names for n in names):
                    ok = True
                    break
        for h in handles:
            with contextlib.suppress(Exception):
                h.undeclare()
        return ok


def _sample_of(zs: Any, zenoh: Any) -> Sample:
    """A :class:`Sample` from a Zenoh sample (the sender and sequence from the attachment)."""
    kind: Literal["put", "delete"] = "delete" if zs.kind == zenoh.SampleKind.DELETE else "put"
    att = zs.attachment
    source, seq = "~live", 0
    if att is not None:
        text = att.to_bytes().decode("utf-8", "replace")
        name, _, number = text.rpartition(":")
        if name and number.isdigit():
            source, seq = name, int(number)
    return Sample(str(zs.key_expr), zs.payload.to_bytes(), kind, source, seq)


def free_local_endpoint() -> str:
    """A TCP endpoint on the loopback with a port that is free now (for simulations)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"tcp/127.0.0.1:{port}"

