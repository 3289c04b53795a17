"""The speech queue: utterances play one after another, never overlapping, never blocking.

:meth:`SpeechQueue.say` returns at once; a task plays the waiting utterances in order through
the engine (``curio/speech/engines.py``). At most ``max_waiting`` utterances wait: when more
arrive the oldest waiting one is dropped (a tour that moves on does not queue stale speech),
and with ``max_waiting = 1`` only the newest waits (the original ``Speaker`` behaviour). When
the engine fails for good (:class:`~curio.speech.engines.SpeechError`) speech turns off with a
warning; the rover goes on silently.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque

from .engines import SilentEngine, SpeechEngine, SpeechError, Utterance

__all__ = ["SpeechQueue"]

log = logging.getLogger("curio.speech")

HISTORY = 200  # utterances kept in ``asked`` and ``played``


class SpeechQueue:
    """Plays utterances through ``engine`` one at a time.

    Args:
        engine: the speech engine (None: silent).
        max_waiting: how many utterances may wait behind the one playing (>= 1).

    Attributes:
        asked: the last ``HISTORY`` utterances asked for, in order (for tests and the kiosk's
            history; bounded: a rover talks all day for weeks).
        played: the last ``HISTORY`` utterances handed to the engine, in order.
        dropped: how many waiting utterances were dropped for newer ones.
    """

    def __init__(self, engine: SpeechEngine | None = None, max_waiting: int = 8) -> None:
        if max_waiting < 1:
            raise ValueError(f"max_waiting must be >= 1, got {max_waiting}")
        self.engine: SpeechEngine = engine if engine is not None else SilentEngine()
        self.max_waiting = max_waiting
        self.waiting: deque[Utterance] = deque()
        self.asked: deque[Utterance] = deque(maxlen=HISTORY)
        self.played: deque[Utterance] = deque(maxlen=HISTORY)
        self.dropped = 0
        self.task: asyncio.Task[None] | None = None
        self.speaking: Utterance | None = None

    @property
    def available(self) -> bool:
        """Whether utterances are really spoken."""
        return self.engine.available

    def say(self, text: str, language: str = "", voice: str = "") -> None:
        """Queue ``text`` (blanks collapsed; empty text is ignored); returns at once."""
        clean = " ".join(text.split())
        if not clean:
            return
        utterance = Utterance(clean, language, voice)
        self.asked.append(utterance)
        if not self.engine.available:
            log.info("would say: %s", clean)
            return
        self.waiting.append(utterance)
        while len(self.waiting) > self.max_waiting:
            self.waiting.popleft()
            self.dropped += 1
        if self.task is None or self.task.done():
            try:
                self.task = asyncio.get_running_loop().create_task(self._play(), name="speech")
            except RuntimeError:  # no running loop (a synchronous caller): nothing plays
                self.waiting.clear()

    async def _play(self) -> None:
        while self.waiting:
            utterance = self.waiting.popleft()
            self.played.append(utterance)
            self.speaking = utterance
            try:
                await self.engine.speak(utterance)
            except SpeechError as exc:
                log.warning("%s; speech is off", exc)
                self.engine = SilentEngine()
                self.waiting.clear()
                return
            finally:
                self.speaking = None

    async def idle(self) -> None:
        """Wait until everything queued has been played."""
        while self.task is not None and not self.task.done():
            await asyncio.shield(self.task)

    async def close(self) -> None:
        """Stop speaking: drop what waits, cut the current utterance short."""
        self.waiting.clear()
        with contextlib.suppress(Exception):
            await self.engine.stop()
        if self.task is not None:
            self.task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self.task
