"""Spoken tour messages, without ever blocking the event loop: the tree's :class:`Speaker`.

:class:`Speaker` is the behaviour tree's face of the speech subsystem (``curio/speech``): a
:class:`~curio.speech.queue.SpeechQueue` in front of a
:class:`~curio.speech.engines.SpeechEngine` (espeak-ng unless another engine is given).
``say`` returns at once; one utterance plays at a time; a message that arrives while another
plays waits, and only the newest waiting message is kept (a tour that moves on does not queue
up stale speech). Without espeak-ng (``shutil.which``) or with ``bt.speak = false`` it only
logs.
"""

from __future__ import annotations

import asyncio
import logging

from curio.speech.engines import EspeakNgEngine, SpeechEngine
from curio.speech.queue import SpeechQueue

__all__ = ["Speaker"]

log = logging.getLogger("curio.bt.speech")


class Speaker:
    """Speak short texts for the visitors.

    Args:
        enabled: ``cfg.bt.speak``.
        program: the speech program looked up on ``PATH`` (for the espeak-ng engine).
        voice_args: extra arguments (e.g. ``["-s", "150"]`` for words per minute).
        engine: another speech engine instead of espeak-ng.
    """

    def __init__(self, enabled: bool = True, program: str = "espeak-ng",
                 voice_args: list[str] | None = None, engine: SpeechEngine | None = None) -> None:
        chosen = engine if engine is not None else EspeakNgEngine(program, voice_args)
        self.queue = SpeechQueue(chosen if enabled else None, max_waiting=1)

    @property
    def available(self) -> bool:
        """Whether texts are really spoken."""
        return self.queue.available

    @property
    def spoken(self) -> list[str]:
        """Every text asked for, in order."""
        return [u.text for u in self.queue.asked]

    @property
    def played(self) -> list[str]:
        """The texts handed to the engine, in order."""
        return [u.text for u in self.queue.played]

    @property
    def _task(self) -> asyncio.Task[None] | None:
        """The playing task (tests await it)."""
        return self.queue.task

    def say(self, text: str, language: str = "", voice: str = "") -> None:
        """Speak ``text`` soon (in ``language`` / ``voice`` when given); returns at once."""
        self.queue.say(text, language, voice)

    async def close(self) -> None:
        """Stop speaking (terminate a running utterance)."""
        await self.queue.close()
