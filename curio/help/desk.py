"""The help desk: every help request reaches a person, and how long it waited is recorded.

:class:`HelpDesk` is a part that follows ``/events``:

* ``help.requested`` (from the tree: the way is blocked — ``Ask4Help`` —, the rover is lost,
  the battery is critical, docking failed; ``detail.reason``, ``blocked`` when absent) opens an
  episode: the rover **says** the configured request for that reason (``help.blocked_message``
  "Excuse me, could you help me? My way is blocked.", ``help.lost_message``,
  ``help.battery_message``, ``help.dock_message``), and says it again every ``help.repeat_s``
  (at most ``help.max_repeats`` times: polite, not nagging); ``/help`` (latched
  :class:`~curio.core.messages.HelpState`) tells the dashboard to **play its sound**
  (``sound`` true at the request and at each repeat) and what blocks the rover
  (``blocked_at``, from ``/help_blockage``); a **notification** goes to every channel
  (:mod:`curio.help.notify`).
* ``help.resolved`` closes it: ``/help`` inactive, a notification ("help no longer needed"),
  and the event ``help.answered`` with ``waited_s`` (request to answer, simulated or real
  seconds), ``help_reason`` and ``answer`` (``clear``, ``help_done``, ``found``, ``charged``,
  ``timeout``, ``preempted``): the event log keeps it for the daily report.
* Other kinds in ``help.notify_kinds`` (``battery.critical``, ``dock.failed``,
  ``tour.skipped``) are notified as they come.

Nothing here blocks the loop: speech goes through a :class:`~curio.speech.queue.SpeechQueue`,
notifications through the :class:`~curio.help.notify.Notifier`'s queues.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import Event, HelpState
from curio.core.topics import EVENTS, HELP, HELP_BLOCKAGE
from curio.speech.queue import SpeechQueue

from .notify import Notification, Notifier

__all__ = ["HelpDesk"]

log = logging.getLogger("curio.help")

TITLES = {
    "help.requested": ("{robot} needs help", 4, ("sos",)),
    "help.resolved": ("{robot}: help no longer needed", 2, ("white_check_mark",)),
    "battery.critical": ("{robot}: battery critical", 5, ("battery",)),
    "dock.failed": ("{robot} could not dock", 4, ("electric_plug",)),
    "tour.skipped": ("{robot} skipped a tour", 3, ("calendar",)),
}


@dataclass
class _Episode:
    reason: str
    message: str
    spoken: str
    since_s: float
    wall_s: float
    repeats: int = 0
    next_say_s: float = 0.0


class HelpDesk:
    """Turns help events into speech, a dashboard sound, notifications and answer times.

    Args:
        cfg: the whole configuration (``[help]``, the robot's name, ``bt.speak``).
        bus, clock: injected.
        speech: where requests are said (None: a silent queue).
        notifier: where notifications go (None: built from ``[help]``).
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock, speech: SpeechQueue | None = None,
                 notifier: Notifier | None = None) -> None:
        self.cfg = cfg
        self.hcfg = cfg.help
        self.bus = bus
        self.clock = clock
        self.speech = speech if speech is not None else SpeechQueue(max_waiting=1)
        self.notifier = notifier if notifier is not None else Notifier(cfg.help, bus, clock)
        self.episode: _Episode | None = None
        self.answered: list[float] = []
        self.bus.publish(HELP, HelpState(clock.now()))

    def spoken_request(self, reason: str) -> str:
        """What the rover says for a request of ``reason``."""
        h = self.hcfg
        return {"lost": h.lost_message, "battery_critical": h.battery_message,
                "dock_failed": h.dock_message}.get(reason, h.blocked_message)

    # --- events -------------------------------------------------------------------------------
    def on_event(self, ev: Event) -> None:
        """Handle one event from ``/events``."""
        if ev.kind == "help.requested":
            self._requested(ev)
        elif ev.kind == "help.resolved":
            self._resolved(ev)
        elif ev.kind in self.hcfg.notify_kinds and ev.kind in TITLES:
            self._notify(ev.kind, str(ev.detail.get("message", ev.kind)), ev.detail)

    def _requested(self, ev: Event) -> None:
        reason = str(ev.detail.get("reason") or "blocked")
        spoken = self.spoken_request(reason)
        now = self.clock.now()
        self.episode = _Episode(reason, str(ev.detail.get("message", spoken)), spoken, now,
                                self.clock.wall_time(), next_say_s=now + self.hcfg.repeat_s)
        self._say(spoken)
        self._publish(sound=True)
        self._notify("help.requested", f"{spoken} ({self._why(reason)})", ev.detail)

    def _resolved(self, ev: Event) -> None:
        ep = self.episode
        if ep is None:
            return
        self.episode = None
        waited = round(self.clock.now() - ep.since_s, 3)
        self.answered.append(waited)
        answer = str(ev.detail.get("reason", ""))
        self.bus.publish(EVENTS, Event(self.clock.now(), "help.answered", {
            "help_reason": ep.reason, "answer": answer, "waited_s": waited,
            "repeats": ep.repeats}))
        self._publish(sound=False)
        self._notify("help.resolved", f"{ev.detail.get('message', 'Resolved')} (after "
                     f"{waited:.0f} s: {answer})", {**ev.detail, "help_reason": ep.reason})

    # --- the loop -----------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        """Say the request again when it is due."""
        ep = self.episode
        if ep is None or now < ep.next_say_s:
            return
        ep.next_say_s = now + self.hcfg.repeat_s
        if ep.repeats >= self.hcfg.max_repeats:
            return
        ep.repeats += 1
        self._say(ep.spoken)
        self._publish(sound=True)

    async def run(self) -> None:
        """Follow ``/events`` and repeat requests until cancelled."""
        sub = self.bus.subscribe(EVENTS)
        try:
            async for now in self.clock.every(0.5):
                for ev in sub.drain():
                    self.on_event(ev)
                self.tick(now)
        finally:
            sub.close()

    async def close(self) -> None:
        """Stop speaking and sending."""
        await self.speech.close()
        await self.notifier.close()

    # --- helpers ------------------------------------------------------------------------------
    @staticmethod
    def _why(reason: str) -> str:
        return {"lost": "lost", "battery_critical": "battery critical",
                "dock_failed": "could not dock"}.get(reason, "way blocked")

    def _say(self, text: str) -> None:
        if self.hcfg.speak:
            self.speech.say(text)

    def state(self, sound: bool = False) -> HelpState:
        """The open request as a message."""
        ep = self.episode
        if ep is None:
            return HelpState(self.clock.now())
        blockage = self.bus.latest(HELP_BLOCKAGE)
        at = None
        if ep.reason == "blocked" and blockage is not None and blockage.circles:
            xs = [c[0] for c in blockage.circles]
            ys = [c[1] for c in blockage.circles]
            at = (round(sum(xs) / len(xs), 3), round(sum(ys) / len(ys), 3))
        return HelpState(self.clock.now(), True, ep.reason, ep.message, ep.since_s, ep.repeats,
                         sound, at)

    def _publish(self, sound: bool) -> None:
        self.bus.publish(HELP, self.state(sound))

    def _notify(self, kind: str, message: str, detail: dict[str, Any]) -> None:
        if kind not in self.hcfg.notify_kinds:
            return
        title, priority, tags = TITLES[kind]
        robot = self.cfg.robot.name
        plain = {k: v for k, v in detail.items()
                 if v is None or isinstance(v, (str, int, float, bool))}
        self.notifier.notify(Notification(kind, title.format(robot=robot.capitalize()),
                                          message, priority, tags, robot,
                                          self.clock.wall_time(), plain))

    def test_notification(self) -> Notification:
        """A test message on every channel (the dashboard's "send a test" button)."""
        robot = self.cfg.robot.name
        note = Notification("notify.test", f"{robot.capitalize()}: test notification",
                            "This is a test: notifications from the rover reach you.", 2,
                            ("test_tube",), robot, self.clock.wall_time())
        self.notifier.notify(note)
        return note
