"""Helpers shared by the device drivers: timed waits on the injected clock and the systemd
readiness/watchdog notifier.

The clock helpers use only the :class:`~curio.core.clock.Clock` protocol (``now``, ``sleep_until``),
so a driver works on the real clock on the rover and on the simulated clock in emulated mode.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import Mapping
from typing import Any

from curio.core.clock import Clock

__all__ = ["SystemdNotifier", "wait_event"]


async def wait_event(clock: Clock, event: asyncio.Event, timeout_s: float) -> bool:
    """Wait for ``event`` at most ``timeout_s`` of clock time; return ``event.is_set()``."""
    if event.is_set():
        return True
    waiter = asyncio.ensure_future(event.wait())
    timer = asyncio.ensure_future(clock.sleep_until(clock.now() + max(0.0, timeout_s)))
    try:
        await asyncio.wait({waiter, timer}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in (waiter, timer):
            if not task.done():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
    return event.is_set()


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
        from curio.core.topics import HEALTH

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
