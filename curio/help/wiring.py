"""Help wiring: the help desk and its notifier as parts."""

from __future__ import annotations

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.parts import Part, Parts
from curio.speech.engines import EspeakNgEngine, SilentEngine, SpeechEngine
from curio.speech.queue import SpeechQueue

from .desk import HelpDesk

__all__ = ["build_help"]


def build_help(cfg: Config, bus: Bus, clock: Clock, parts: Parts) -> HelpDesk:
    """Build the help desk (speech through espeak-ng when ``bt.speak`` and installed)."""
    engine: SpeechEngine = SilentEngine()
    if cfg.bt.speak and cfg.help.speak:
        espeak = EspeakNgEngine()
        if espeak.available:
            engine = espeak
    desk = HelpDesk(cfg, bus, clock, SpeechQueue(engine, max_waiting=1))
    parts.add(Part("help", run=desk.run, close=desk.close))
    parts.add(Part("help.notify", run=desk.notifier.run, close=desk.notifier.close))
    return desk
