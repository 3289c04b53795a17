"""Speech engines behind one interface, so a better local engine can replace espeak-ng.

A :class:`SpeechEngine` speaks one :class:`Utterance` at a time: ``await engine.speak(u)``
returns when it has been said (or failed) and ``await engine.stop()`` cuts it short. Engines
run their work as subprocesses or threads; they never block the event loop. The queue in
``curio/speech/queue.py`` makes sure utterances never overlap.

* :class:`EspeakNgEngine` — ``espeak-ng`` (Debian package ``espeak-ng``) as a subprocess; the
  utterance's voice (``-v en-gb+f3``) or else its language (``-v fr``) picks the voice.
* :class:`SilentEngine` — says nothing and logs the text (no speaker, or ``bt.speak = false``).

Another engine (Piper, RHVoice, a cloud-free neural TTS) implements the same three members.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import shutil
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

__all__ = ["EspeakNgEngine", "SilentEngine", "SpeechEngine", "SpeechError", "Utterance"]

log = logging.getLogger("curio.speech")


class SpeechError(RuntimeError):
    """The engine cannot speak any more (its program vanished, the sound device failed)."""


@dataclass(frozen=True, slots=True)
class Utterance:
    """Text to say, with an optional BCP-47 ``language`` and an engine ``voice`` name."""

    text: str
    language: str = ""
    voice: str = ""


@runtime_checkable
class SpeechEngine(Protocol):
    """What the speech queue needs from an engine."""

    @property
    def available(self) -> bool:
        """Whether utterances are really spoken."""
        ...

    async def speak(self, utterance: Utterance) -> None:
        """Say ``utterance`` and return when done. Raises :class:`SpeechError` when the engine
        cannot speak any more."""
        ...

    async def stop(self) -> None:
        """Cut the current utterance short (no-op when silent)."""
        ...


class SilentEngine:
    """Logs what it would say."""

    @property
    def available(self) -> bool:
        """Never: nothing is spoken."""
        return False

    async def speak(self, utterance: Utterance) -> None:
        """Log the text."""
        log.info("would say: %s", utterance.text)

    async def stop(self) -> None:
        """Nothing to stop."""


class EspeakNgEngine:
    """espeak-ng as a subprocess per utterance.

    Args:
        program: looked up on ``PATH`` (``shutil.which``).
        extra_args: more arguments, e.g. ``["-s", "150"]`` (words per minute).
    """

    def __init__(self, program: str = "espeak-ng", extra_args: list[str] | None = None) -> None:
        self.path = shutil.which(program)
        self.extra_args = list(extra_args or [])
        self._proc: asyncio.subprocess.Process | None = None

    @property
    def available(self) -> bool:
        """Whether the program was found."""
        return self.path is not None

    def command(self, utterance: Utterance) -> list[str]:
        """The argument vector for ``utterance`` (the text after ``--``, never parsed)."""
        assert self.path is not None
        voice = utterance.voice or utterance.language
        args = [self.path, *self.extra_args]
        if voice:
            args += ["-v", voice]
        return [*args, "--", utterance.text]

    async def speak(self, utterance: Utterance) -> None:
        """Run espeak-ng and wait for it (the loop goes on meanwhile)."""
        if self.path is None:
            raise SpeechError("espeak-ng is not installed")
        try:
            self._proc = await asyncio.create_subprocess_exec(
                *self.command(utterance), stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
            await self._proc.wait()
        except OSError as exc:
            self.path = None
            raise SpeechError(f"espeak-ng failed ({exc})") from exc
        finally:
            self._proc = None

    async def stop(self) -> None:
        """Terminate a running espeak-ng."""
        proc = self._proc
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
