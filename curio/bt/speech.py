"""Spoken tour messages through espeak-ng, without ever blocking the event loop.

:class:`Speaker` starts ``espeak-ng`` with ``asyncio.create_subprocess_exec`` in a task and
returns at once. One utterance plays at a time; a message that arrives while another plays
waits, and only the newest waiting message is kept (a tour that moves on does not queue up
stale speech). Without espeak-ng (``shutil.which``) or with ``bt.speak = false`` it only logs.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import shutil

__all__ = ["Speaker"]

log = logging.getLogger("curio.bt.speech")


class Speaker:
    """Speak short texts for the visitors.

    Args:
        enabled: ``cfg.bt.speak``.
        program: the speech program looked up on ``PATH``.
        voice_args: extra arguments (e.g. ``["-s", "150"]`` for words per minute).
    """

    def __init__(self, enabled: bool = True, program: str = "espeak-ng",
                 voice_args: list[str] | None = None) -> None:
        self.path = shutil.which(program) if enabled else None
        self.voice_args = list(voice_args or [])
        self._waiting: str | None = None
        self._task: asyncio.Task[None] | None = None
        self._proc: asyncio.subprocess.Process | None = None
        self.spoken: list[str] = []
        self.played: list[str] = []

    @property
    def available(self) -> bool:
        """Whether texts are really spoken."""
        return self.path is not None

    def say(self, text: str) -> None:
        """Speak ``text`` soon; returns at once (needs a running loop when speech is on)."""
        text = " ".join(text.split())
        if not text:
            return
        self.spoken.append(text)
        if self.path is None:
            log.info("would say: %s", text)
            return
        self._waiting = text
        if self._task is None or self._task.done():
            try:
                self._task = asyncio.get_running_loop().create_task(self._play(),
                                                                    name="espeak-ng")
            except RuntimeError:  # no loop (a synchronous test): nothing to play on
                self._waiting = None

    async def _play(self) -> None:
        assert self.path is not None
        while self._waiting is not None:
            text, self._waiting = self._waiting, None
            self.played.append(text)
            try:
                self._proc = await asyncio.create_subprocess_exec(
                    self.path, *self.voice_args, "--", text,
                    stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.DEVNULL,
                    stderr=asyncio.subprocess.DEVNULL)
                await self._proc.wait()
            except OSError as exc:
                log.warning("espeak-ng failed (%s); speech is off", exc)
                self.path = None
                return
            finally:
                self._proc = None

    async def close(self) -> None:
        """Stop speaking (terminate a running espeak-ng)."""
        self._waiting = None
        proc = self._proc
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task
