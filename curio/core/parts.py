"""Parts: the long-lived pieces of the application and the interface that registers them.

A subsystem's wiring function (``curio/*/wiring.py``) constructs its objects and registers each
running piece as a :class:`Part` (a coroutine run as a task, an optional cleanup) on a
:class:`Parts` registry, plus the coroutines that stop the motors (halt hooks). The composition
root (``curio/app.py``) owns the registry and runs the parts; nothing below it imports the root.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

__all__ = ["Part", "Parts"]


@dataclass
class Part:
    """A running piece of the application.

    Attributes:
        name: for logs and health.
        run: the long-lived coroutine function (cancelled at shutdown); None if passive.
        close: optional cleanup, awaited after every task has stopped.
    """

    name: str
    run: Callable[[], Awaitable[None]] | None = None
    close: Callable[[], Awaitable[None]] | None = None


@dataclass
class Parts:
    """What the wiring functions register: parts, in start order, and motor-stop hooks.

    Attributes:
        parts: every registered part, in registration (= start) order.
        halt_hooks: coroutines that stop the motors; run first at shutdown and when a part
            crashes.
    """

    parts: list[Part] = field(default_factory=list)
    halt_hooks: list[Callable[[], Awaitable[None]]] = field(default_factory=list)

    def add(self, part: Part) -> None:
        """Register a part."""
        self.parts.append(part)

    def add_halt_hook(self, hook: Callable[[], Awaitable[None]]) -> None:
        """Register a coroutine that stops the motors."""
        self.halt_hooks.append(hook)
