"""Help that reaches a person: the spoken request and its repeats, the dashboard's sound, the
notifications (webhook, ntfy) off the loop with retries, the answer time."""

from __future__ import annotations

import json
from typing import Any

from aiohttp import web

from curio.core.clock import RealClock
from curio.core.config import Config, HelpConfig
from curio.core.messages import Event
from curio.core.topics import EVENTS, HELP, make_bus
from curio.help.desk import HelpDesk
from curio.help.notify import Notification, Notifier, NtfyChannel, WebhookChannel
from curio.speech.queue import SpeechQueue

from .bt_fakes import ManualClock


class Recorder:
    """A notifier that keeps what it is given."""

    def __init__(self) -> None:
        self.notes: list[Notification] = []
        self.channels: list[Any] = []

    def notify(self, note: Notification) -> None:
        self.notes.append(note)

    async def close(self) -> None:
        return None


def _desk(**help_cfg: Any) -> tuple[HelpDesk, Any, ManualClock, Recorder, SpeechQueue]:
    cfg = Config(help=HelpConfig(**help_cfg))
    bus = make_bus()
    clock = ManualClock()
    speech = SpeechQueue(max_waiting=8)
    rec = Recorder()
    desk = HelpDesk(cfg, bus, clock, speech, rec)  # type: ignore[arg-type]
    return desk, bus, clock, rec, speech


def test_the_request_is_said_repeated_politely_notified_and_its_wait_recorded() -> None:
    desk, bus, clock, rec, speech = _desk(repeat_s=60.0, max_repeats=2)
    events = bus.subscribe(EVENTS)
    desk.on_event(Event(0.0, "help.requested", {"trigger": "blocked",
                                                "message": "HELP ME! Something blocks my way."}))
    assert [u.text for u in speech.asked] == ["Excuse me, could you help me? My way is blocked."]
    state = bus.latest(HELP)
    assert state is not None and state.active and state.sound and state.reason == "blocked"
    (note,) = rec.notes
    assert note.kind == "help.requested" and note.title == "Curio needs help"
    for t in (30.0, 60.0, 90.0, 120.0, 180.0, 240.0):
        clock.t = t
        desk.tick(t)
    assert len(speech.asked) == 3  # the request and two repeats (help.max_repeats), no more
    assert bus.latest(HELP).repeats == 2  # type: ignore[union-attr]
    clock.t = 250.0
    desk.on_event(Event(250.0, "help.resolved", {"reason": "clear", "message": "Thanks!"}))
    assert not bus.latest(HELP).active  # type: ignore[union-attr]
    (answered,) = [e for e in events.drain() if e.kind == "help.answered"]
    assert answered.detail == {"help_reason": "blocked", "answer": "clear", "waited_s": 250.0,
                               "repeats": 2}
    assert rec.notes[-1].kind == "help.resolved"


def test_each_reason_has_its_own_words_and_other_kinds_are_notified() -> None:
    desk, _, _, rec, speech = _desk(lost_message="Where am I?", notify_kinds=[
        "help.requested", "battery.critical"])
    desk.on_event(Event(0.0, "help.requested", {"reason": "lost"}))
    desk.on_event(Event(1.0, "battery.critical", {"message": "Battery critical (6.2 V)."}))
    desk.on_event(Event(2.0, "tour.skipped", {"message": "skipped"}))  # not in notify_kinds
    assert speech.asked[0].text == "Where am I?"
    assert [n.kind for n in rec.notes] == ["help.requested", "battery.critical"]
    assert rec.notes[1].priority == 5


async def test_webhook_and_ntfy_are_delivered_retried_and_never_block(aiohttp_server: Any
                                                                      ) -> None:
    got: list[tuple[str, Any, dict[str, str]]] = []
    fails = {"n": 2}

    async def hook(request: web.Request) -> web.Response:
        if fails["n"] > 0:
            fails["n"] -= 1
            return web.Response(status=503)
        got.append(("hook", await request.json(), dict(request.headers)))
        return web.Response(status=204)

    async def topic(request: web.Request) -> web.Response:
        got.append(("ntfy", await request.text(), dict(request.headers)))
        return web.Response(text="{}")

    app = web.Application()
    app.router.add_post("/hook", hook)
    app.router.add_post("/curio", topic)
    server = await aiohttp_server(app)
    base = f"http://127.0.0.1:{server.port}"
    bus = make_bus()
    events = bus.subscribe(EVENTS)
    cfg = HelpConfig(webhook_urls=[f"{base}/hook"], ntfy_urls=[f"{base}/curio"], retries=3,
                     backoff_s=0.01)
    notifier = Notifier(cfg, bus, RealClock())
    note = Notification("help.requested", "Curio needs help", "My way is blocked.", 4,
                        ("sos",), "curio", 1.7e9, {"reason": "blocked"})
    assert await notifier.deliver(notifier.channels[0], note)  # after two 503s
    assert await notifier.deliver(notifier.channels[1], note)
    hook_body = next(b for k, b, _ in got if k == "hook")
    assert hook_body["kind"] == "help.requested" and hook_body["detail"] == {"reason": "blocked"}
    _, text, headers = next(g for g in got if g[0] == "ntfy")
    assert text == "My way is blocked." and headers["Title"] == "Curio needs help"
    assert headers["Priority"] == "4" and headers["Tags"] == "sos"
    sent = [e for e in events.drain() if e.kind == "notify.sent"]
    assert [e.detail["attempts"] for e in sent] == [3, 1]
    # A channel that never answers: notify.failed after the retries; notify() returns at once.
    dead = Notifier(HelpConfig(retries=1, backoff_s=0.01, timeout_s=0.5), bus, RealClock(),
                    channels=[WebhookChannel("http://127.0.0.1:9/none")])
    dead.notify(note)  # only queued
    assert not await dead.deliver(dead.channels[0], note)
    (failed,) = [e for e in events.drain() if e.kind == "notify.failed"]
    assert failed.detail["attempts"] == 2 and failed.detail["error"]
    assert isinstance(NtfyChannel(base).name, str) and json.dumps(hook_body)


def test_the_speech_history_is_bounded() -> None:
    """A rover that talks all day for weeks keeps only the latest utterances (a soak's object
    census found every sentence of the day kept)."""
    from curio.speech.queue import HISTORY

    speech = SpeechQueue()
    for k in range(HISTORY + 50):
        speech.say(f"stop {k}")
    assert len(speech.asked) == HISTORY
    assert speech.asked[-1].text == f"stop {HISTORY + 49}" and speech.asked[0].text == "stop 50"
