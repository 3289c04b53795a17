"""Notifications to people who are not looking: webhooks and ntfy-style topics.

Two channels, configured in ``[help]``:

* **Webhook** (``help.webhook_urls``): ``POST`` of a JSON body ``{"robot", "kind", "title",
  "message", "priority", "wall_time", "detail"}`` (``Content-Type: application/json``); any 2xx
  answer is a delivery.
* **ntfy** (``help.ntfy_urls``, a topic URL such as ``https://ntfy.sh/curio-lobby`` or a
  self-hosted server): ``POST`` of the message as plain text with the headers ``Title``,
  ``Priority`` (1–5) and ``Tags``, as ntfy's publish API takes them.

:class:`Notifier` never blocks the event loop: :meth:`Notifier.notify` only puts the message on
each channel's bounded queue (the oldest undelivered one is dropped when it is full, and
counted); one task per channel sends them in order with aiohttp, each attempt limited to
``help.timeout_s``, retried ``help.retries`` times with exponential back-off from
``help.backoff_s`` up to ``help.backoff_max_s`` (on the injected clock). Outcomes are events:
``notify.sent`` (channel, kind, attempts) and ``notify.failed`` (channel, kind, error,
attempts). The rover has no internet in most buildings: the URLs are expected on the local
network (a self-hosted ntfy, a chat bot, a building system).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Protocol

import aiohttp

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import HelpConfig
from curio.core.messages import Event
from curio.core.topics import EVENTS

__all__ = ["Channel", "Notification", "Notifier", "NtfyChannel", "WebhookChannel"]

log = logging.getLogger("curio.help.notify")


@dataclass(frozen=True)
class Notification:
    """One message for people: ``kind`` (the event kind, e.g. ``help.requested``), a short
    ``title``, the ``message``, ``priority`` 1 (min) .. 5 (urgent), ntfy ``tags``, the robot's
    name, the wall time it happened (UNIX seconds) and the event's ``detail``."""

    kind: str
    title: str
    message: str
    priority: int = 3
    tags: tuple[str, ...] = ()
    robot: str = "curio"
    wall_time: float = 0.0
    detail: dict[str, Any] = field(default_factory=dict)


class Channel(Protocol):
    """Where notifications go."""

    name: str

    async def send(self, session: aiohttp.ClientSession, note: Notification,
                   timeout_s: float) -> None:
        """Deliver one notification; raise on failure."""


class WebhookChannel:
    """HTTP ``POST`` of a JSON body to ``url``."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.name = f"webhook {url}"

    async def send(self, session: aiohttp.ClientSession, note: Notification,
                   timeout_s: float) -> None:
        """POST the notification as JSON; raise unless the answer is 2xx."""
        body = {"robot": note.robot, "kind": note.kind, "title": note.title,
                "message": note.message, "priority": note.priority,
                "wall_time": note.wall_time, "detail": note.detail}
        data = json.dumps(body, default=str).encode("utf-8")
        async with session.post(self.url, data=data,
                                headers={"Content-Type": "application/json"},
                                timeout=aiohttp.ClientTimeout(total=timeout_s)) as resp:
            if resp.status // 100 != 2:
                raise RuntimeError(f"HTTP {resp.status}")


class NtfyChannel:
    """ntfy-style publish: ``POST`` the text to a topic URL with Title/Priority/Tags."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.name = f"ntfy {url}"

    async def send(self, session: aiohttp.ClientSession, note: Notification,
                   timeout_s: float) -> None:
        """POST the message; raise unless the answer is 2xx."""
        headers = {"Title": note.title, "Priority": str(max(1, min(5, note.priority)))}
        if note.tags:
            headers["Tags"] = ",".join(note.tags)
        async with session.post(self.url, data=note.message.encode("utf-8"), headers=headers,
                                timeout=aiohttp.ClientTimeout(total=timeout_s)) as resp:
            if resp.status // 100 != 2:
                raise RuntimeError(f"HTTP {resp.status}")


class Notifier:
    """Sends notifications on every configured channel (see the module docstring).

    Args:
        cfg: ``[help]``.
        bus, clock: injected (events, back-off sleeps).
        channels: override the channels built from ``cfg`` (tests).
    """

    def __init__(self, cfg: HelpConfig, bus: Bus, clock: Clock,
                 channels: list[Channel] | None = None) -> None:
        self.cfg = cfg
        self.bus = bus
        self.clock = clock
        self.channels: list[Channel] = channels if channels is not None else [
            *(WebhookChannel(u) for u in cfg.webhook_urls),
            *(NtfyChannel(u) for u in cfg.ntfy_urls)]
        self._queues: list[deque[Notification]] = [deque() for _ in self.channels]
        self._wake: list[asyncio.Event] = [asyncio.Event() for _ in self.channels]
        self.sent = 0
        self.failed = 0
        self.dropped = 0
        self._session: aiohttp.ClientSession | None = None

    def notify(self, note: Notification) -> None:
        """Queue ``note`` on every channel; returns at once."""
        for queue, wake in zip(self._queues, self._wake, strict=True):
            if len(queue) >= self.cfg.queue_size:
                queue.popleft()
                self.dropped += 1
            queue.append(note)
            wake.set()

    async def run(self) -> None:
        """One sender per channel, until cancelled."""
        if not self.channels:
            return
        self._session = aiohttp.ClientSession()
        try:
            await asyncio.gather(*(self._sender(i) for i in range(len(self.channels))))
        finally:
            await self.close()

    async def close(self) -> None:
        """Close the HTTP session."""
        session, self._session = self._session, None
        if session is not None:
            with contextlib.suppress(Exception):
                await session.close()

    async def _sender(self, i: int) -> None:
        queue, wake = self._queues[i], self._wake[i]
        while True:
            while not queue:
                wake.clear()
                await wake.wait()
            note = queue.popleft()
            await self.deliver(self.channels[i], note)

    async def deliver(self, channel: Channel, note: Notification) -> bool:
        """Send ``note`` on ``channel`` with retries and back-off; whether it arrived."""
        session = self._session
        own = session is None
        if session is None:
            session = aiohttp.ClientSession()
        delay = self.cfg.backoff_s
        error = ""
        try:
            for attempt in range(1, self.cfg.retries + 2):
                try:
                    await channel.send(session, note, self.cfg.timeout_s)
                except (aiohttp.ClientError, TimeoutError, RuntimeError, OSError) as exc:
                    error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                    log.info("notification to %s failed (attempt %d): %s", channel.name,
                             attempt, error)
                    if attempt <= self.cfg.retries:
                        await self.clock.sleep(delay)
                        delay = min(2.0 * delay, self.cfg.backoff_max_s)
                    continue
                self.sent += 1
                self._event("notify.sent", channel=channel.name, kind=note.kind,
                            attempts=attempt)
                return True
        finally:
            if own:
                await session.close()
        self.failed += 1
        self._event("notify.failed", channel=channel.name, kind=note.kind, error=error,
                    attempts=self.cfg.retries + 1)
        return False

    def _event(self, event_kind: str, **detail: Any) -> None:
        self.bus.publish(EVENTS, Event(self.clock.now(), event_kind, detail))
