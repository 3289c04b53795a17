"""Fixed-rate loops and timed waits on the injected clock (only the ``Clock`` protocol)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from curio.core.clock import Clock

__all__ = ["wait_until"]


async def wait_until(clock: Clock, predicate: Callable[[], bool], timeout_s: float,
                     event: asyncio.Event, poll_s: float = 0.05) -> bool:
    """Wait until ``predicate()`` holds, re-checking whenever ``event`` is set (and at least
    every ``poll_s``); return False after ``timeout_s`` of clock time."""
    deadline = clock.now() + timeout_s
    while not predicate():
        now = clock.now()
        if now >= deadline:
            return False
        event.clear()
        waiter = asyncio.ensure_future(event.wait())
        timer = asyncio.ensure_future(clock.sleep_until(min(deadline, now + poll_s)))
        try:
            await asyncio.wait({waiter, timer}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            waiter.cancel()
            timer.cancel()
    return True


class Pacer:
    """Holds a simulated clock until the peer has received the bytes this side wrote.

    In emulated mode the driver and the emulator talk through a pseudo-terminal while a
    ``SimClock`` runs virtual time as fast as the CPU allows. The kernel delivers pty bytes a
    little later (a work queue), and meanwhile virtual time could race ahead and trip link
    timeouts that real hardware never would. :meth:`settle` keeps this task runnable (so the
    clock cannot move on) until ``peer_received()`` has caught up with ``sent()``, for at most
    ``max_spins`` loop turns; bytes that never arrive (the peer closed the port) are written
    off. Without a peer (real hardware) it does nothing.
    """

    def __init__(self, clock: Clock, sent: Callable[[], int],
                 peer_received: Callable[[], int] | None = None, max_spins: int = 20000) -> None:
        self.clock = clock
        self.sent = sent
        self.peer_received = peer_received
        self.max_spins = max_spins
        self._offset = 0
        self.spins = 0
        self.write_offs = 0

    async def settle(self) -> None:
        """Wait (without moving virtual time) until the peer has read what was sent."""
        if self.peer_received is None:
            return
        for _ in range(self.max_spins):
            pending = self.sent() - self._offset - self.peer_received()
            if pending <= 0:
                self._offset += min(0, pending)
                return
            self.spins += 1
            await self.clock.sleep(0.0)
        self._offset += max(0, self.sent() - self._offset - self.peer_received())
        self.write_offs += 1
