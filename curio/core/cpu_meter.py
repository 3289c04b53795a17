"""CPU time per task family on one event loop: what each part of the application costs.

:class:`CpuMeter` installs a task factory on the running loop that wraps every task created
from then on; each step of a task (one ``send``/``throw`` into its coroutine) is timed with the
thread's CPU clock (``time.thread_time``: CPU seconds of the loop's thread, so other load on the
machine and other threads do not count) and added to the task's *label*. A task's label is its
own name — the tasks :class:`curio.app.App` starts are named after their parts
(``sim.physics``, ``ekf``, ``localization`` ...) — or, for a task created without a name
(asyncio's ``Task-N``) from inside a metered task, its parent's label (``contextvars`` are
inherited): every unnamed child task a part spawns is charged to that part.

What no task step covers — the event loop's own machinery (``select``, handles, timers), the
simulated clock's stepping when it runs in the unmetered main task, callbacks scheduled with
``call_soon`` — is the remainder: ``loop_s`` in :meth:`CpuMeter.report`, the process's CPU
minus every label's sum.

Benchmarks use it to tell the application's CPU from the simulator's (``curio bench stack``,
``curio bench pi-budget``); it costs two CPU-clock reads per task step (about 1 µs).
"""

from __future__ import annotations

import asyncio
import contextvars
import re
from collections.abc import Coroutine, Generator
from typing import Any

from curio.core.clock import process_cpu_time, thread_cpu_time

__all__ = ["CpuMeter"]

_LABEL: contextvars.ContextVar[str | None] = contextvars.ContextVar("curio_cpu_label",
                                                                   default=None)
_DEFAULT_NAME = re.compile(r"Task-\d+$")  # asyncio's name for a task created without one


class _Metered(Coroutine[Any, Any, Any]):
    """A coroutine that times every step of the one it wraps and charges it to a label."""

    __slots__ = ("_coro", "_label", "_meter", "_timed")

    def __init__(self, coro: Coroutine[Any, Any, Any], meter: CpuMeter) -> None:
        self._coro = coro
        self._meter = meter
        self._label: str | None = None
        self._timed = False

    def _start(self) -> str:
        """The label, fixed on the first step (the task's name is set by then): the task's
        own name, or its parent's label when it has only asyncio's default ``Task-N``."""
        task = asyncio.current_task()
        name = task.get_name() if task is not None else "?"
        inherited = _LABEL.get()
        label = inherited if inherited is not None and _DEFAULT_NAME.match(name) else name
        _LABEL.set(label)  # inside the task's own context: its children inherit it
        self._label = label
        self._timed = self._meter.meters(label)
        return label

    def send(self, value: Any) -> Any:
        """One step of the wrapped coroutine, timed if its label is metered."""
        label = self._label or self._start()
        if not self._timed:
            return self._coro.send(value)
        t0 = thread_cpu_time()
        try:
            return self._coro.send(value)
        finally:
            self._meter.charge(label, thread_cpu_time() - t0)

    def throw(self, typ: Any, val: Any = None, tb: Any = None) -> Any:
        """Throw into the wrapped coroutine (cancellation), timed if its label is metered."""
        label = self._label or self._start()
        t0 = thread_cpu_time() if self._timed else 0.0
        try:
            if val is None and tb is None:
                return self._coro.throw(typ)
            return self._coro.throw(typ, val, tb)  # pragma: no cover - old-style call
        finally:
            if self._timed:
                self._meter.charge(label, thread_cpu_time() - t0)

    def close(self) -> None:
        """Close the wrapped coroutine."""
        self._coro.close()

    def __await__(self) -> Generator[Any, None, Any]:  # pragma: no cover - tasks call send
        return self._coro.__await__()


class CpuMeter:
    """CPU seconds per task label on the loop it is installed on.

    Use :meth:`install` inside the loop before the tasks to be measured are created, and
    :meth:`report` at the end. ``seconds`` maps a label to its CPU seconds, ``steps`` to its
    number of task steps.

    Args:
        only: time only the labels that start with one of these prefixes (None: every label).
            Timing costs about 1 µs of CPU per step, outside the measured intervals: metering
            only what is to be subtracted (the simulator) leaves the rest nearly undisturbed,
            and the little the meter costs lands in the remainder (the conservative side).
    """

    def __init__(self, only: tuple[str, ...] | None = None) -> None:
        self.only = only
        self.seconds: dict[str, float] = {}
        self.steps: dict[str, int] = {}
        self._cpu0 = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None

    def install(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        """Meter every task created on ``loop`` (default: the running loop) from now on."""
        loop = loop or asyncio.get_running_loop()
        meter = self

        def factory(lp: asyncio.AbstractEventLoop, coro: Any, **kwargs: Any) -> asyncio.Task[Any]:
            return asyncio.Task(_Metered(coro, meter), loop=lp, **kwargs)

        loop.set_task_factory(factory)  # type: ignore[arg-type]
        self._loop = loop
        self._cpu0 = process_cpu_time()

    def uninstall(self) -> None:
        """Stop wrapping new tasks (tasks already wrapped stay metered)."""
        if self._loop is not None:
            self._loop.set_task_factory(None)
            self._loop = None

    def meters(self, label: str) -> bool:
        """Whether steps of tasks labelled ``label`` are timed."""
        return self.only is None or label.startswith(self.only)

    def charge(self, label: str, seconds: float) -> None:
        """Add one step of ``seconds`` CPU seconds to ``label``."""
        self.seconds[label] = self.seconds.get(label, 0.0) + seconds
        self.steps[label] = self.steps.get(label, 0) + 1

    def total(self, prefixes: tuple[str, ...]) -> float:
        """CPU seconds of every label that starts with one of ``prefixes``."""
        return sum(s for label, s in self.seconds.items() if label.startswith(prefixes))

    def report(self) -> dict[str, float]:
        """``{label: seconds}`` plus ``process_s`` (the process's CPU since :meth:`install`)
        and ``loop_s`` (the part of it no metered task step accounts for)."""
        process = process_cpu_time() - self._cpu0
        out = dict(sorted(self.seconds.items(), key=lambda item: -item[1]))
        out["process_s"] = process
        out["loop_s"] = process - sum(self.seconds.values())
        return out
