"""Driver health: each driver's ``/health`` and events (:class:`HealthReporter`), and the systemd
readiness/watchdog notifier that shows them in ``systemctl status curio``."""

from __future__ import annotations

import contextlib
import logging
import socket
from collections.abc import Callable, Mapping
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.messages import DriverHealth, Event
from curio.core.topics import EVENTS, HEALTH

__all__ = ["HealthReporter", "ReportsHealth", "SystemdNotifier"]


class HealthReporter:
    """A driver's ``/health``: its state and message, its counters, and its lost and recovered
    events.

    ``state`` is ``starting``, ``ok``, ``degraded``, ``error`` or ``off``; ``message`` says what
    is wrong and what to do. A driver either sets them (:meth:`set_state`, :meth:`lost`) or
    derives them when asked (``assess``). It publishes with :meth:`publish` (now),
    :meth:`publish_if_due` (from its own loop: on a change, else once a period) or :meth:`run`
    (a fixed-rate task).

    Args:
        name: the driver's name on ``/health``; its events are ``driver.<name>_lost`` and
            ``driver.<name>_recovered``.
        clock: the application clock (stamps).
        bus: the application bus.
        log: where state changes are logged.
        counters: the driver's counters (the same dict: the driver updates it).
        extra: more counters computed at each publication, added after ``counters``.
        assess: derives (state, message) at each publication (instead of :meth:`set_state`).
        publish_unchanged: :meth:`set_state` publishes even when nothing changed.
        period_s: :meth:`publish_if_due` publishes at least this often, seconds.
    """

    def __init__(self, name: str, clock: Clock, bus: Bus, log: logging.Logger,
                 counters: dict[str, float], *,
                 extra: Callable[[], dict[str, float]] | None = None,
                 assess: Callable[[], tuple[str, str]] | None = None,
                 publish_unchanged: bool = False, period_s: float = 1.0) -> None:
        self.name = name
        self.clock = clock
        self.bus = bus
        self.log = log
        self.counters = counters
        self.extra = extra
        self.assess = assess
        self.publish_unchanged = publish_unchanged
        self.period_s = period_s
        self.state = "starting"
        self.message = ""
        self.down_since: float | None = None
        self._published_key: tuple[str, str] | None = None
        self._next_s = 0.0

    def snapshot(self) -> DriverHealth:
        """The health now: state, message and counters."""
        state, message = self.assess() if self.assess is not None else (self.state, self.message)
        counters = dict(self.counters)
        if self.extra is not None:
            counters.update(self.extra())
        return DriverHealth(self.clock.now(), self.name, state, message, counters)

    def publish(self) -> None:
        """Publish ``/health`` now."""
        self.bus.publish(HEALTH, self.snapshot())

    def publish_if_due(self, force: bool = False) -> None:
        """Publish ``/health`` when forced, when the state or message changed since the last
        time, or when ``period_s`` has passed since."""
        health = self.snapshot()
        key = (health.state, health.message)
        now = self.clock.now()
        if force or key != self._published_key or now >= self._next_s:
            self._published_key = key
            self._next_s = now + self.period_s
            self.bus.publish(HEALTH, health)

    async def run(self, period_s: float) -> None:
        """Publish ``/health`` every ``period_s`` until cancelled."""
        async for _ in self.clock.every(period_s):
            self.publish()

    def set_state(self, state: str, message: str) -> None:
        """Set the state and message; publish if either changed (or ``publish_unchanged``). A
        new state, or a new message in state ``error``, is logged."""
        changed = (state, message) != (self.state, self.message)
        if state != self.state or (changed and state == "error"):
            (self.log.info if state == "ok" else self.log.warning)(
                "%s %s: %s", self.name, state, message)
        self.state, self.message = state, message
        if changed or self.publish_unchanged:
            self.publish()

    def event(self, kind: str, **detail: Any) -> None:
        """Publish an event on ``/events``, stamped now."""
        self.bus.publish(EVENTS, Event(self.clock.now(), kind, detail))

    def lost(self, reason: str, message: str | None = None) -> None:
        """The device is down: ``driver.<name>_lost`` (once per outage, with ``reason``) and
        state ``error`` with ``message`` (default: ``reason``)."""
        if self.down_since is None:
            self.down_since = self.clock.now()
            self.event(f"driver.{self.name}_lost", reason=reason)
        self.set_state("error", reason if message is None else message)

    def recovered(self, at_s: float) -> None:
        """The device works again at clock time ``at_s``: ``driver.<name>_recovered`` with how
        long it was down (nothing when it was not down)."""
        if self.down_since is not None:
            down_s, self.down_since = at_s - self.down_since, None
            self.event(f"driver.{self.name}_recovered", down_s=round(down_s, 3))


class ReportsHealth:
    """A driver whose ``/health`` is its :class:`HealthReporter` ``reporter``: its ``state``
    and ``message`` read from there."""

    reporter: HealthReporter

    @property
    def state(self) -> str:
        """``starting``, ``ok``, ``degraded`` or ``error`` (as on ``/health``)."""
        return self.reporter.state

    @property
    def message(self) -> str:
        """What is wrong and what to do (as on ``/health``)."""
        return self.reporter.message


class SystemdNotifier:
    """Tells systemd the service is up and alive (``Type=notify`` with ``WatchdogSec``).

    When ``NOTIFY_SOCKET`` is set (systemd started us), :meth:`run` sends ``READY=1`` once and
    then ``WATCHDOG=1`` every half ``WATCHDOG_USEC``, with a ``STATUS=`` line made of the
    latest ``/health`` state of every driver. The pings come from the event loop, so a loop
    that hangs stops them and systemd restarts the service. Without ``NOTIFY_SOCKET`` it does
    nothing.

    Args:
        clock: the application clock.
        bus: the application bus (``/health`` is read for the status line).
        environ: the process environment (injectable for tests).
    """

    def __init__(self, clock: Clock, bus: Any, environ: Mapping[str, str]) -> None:
        self.clock = clock
        self.bus = bus
        self.address = environ.get("NOTIFY_SOCKET", "")
        usec = environ.get("WATCHDOG_USEC", "")
        self.period_s = int(usec) / 2e6 if usec.isdigit() and int(usec) > 0 else 5.0
        self.sent: list[str] = []

    @property
    def enabled(self) -> bool:
        """True when systemd asked for notifications."""
        return bool(self.address)

    def _send(self, text: str) -> None:
        addr = self.address
        target = "\0" + addr[1:] if addr.startswith("@") else addr
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.connect(target)
            sock.sendall(text.encode("utf-8"))
        self.sent.append(text)

    async def run(self) -> None:
        """Notify until cancelled (returns at once when not under systemd)."""
        if not self.enabled:
            return
        states: dict[str, str] = {}
        sub = self.bus.subscribe(HEALTH, maxsize=256)
        try:
            self._send("READY=1\nSTATUS=starting")
            async for _ in self.clock.every(self.period_s):
                for health in sub.drain():
                    states[health.name] = health.state
                status = ", ".join(f"{k} {v}" for k, v in sorted(states.items())) or "running"
                with contextlib.suppress(OSError):
                    self._send(f"WATCHDOG=1\nSTATUS={status}")
        finally:
            sub.close()
            with contextlib.suppress(OSError):
                self._send("STOPPING=1")
