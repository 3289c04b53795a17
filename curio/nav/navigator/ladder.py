"""The recovery ladder: what the navigator tries when the rover is stuck, before it gives up.

Each time the rover is stuck (no path, the controller blocked or without progress, no
progress towards the goal) :meth:`RecoveryLadder.climb` starts the next rung of
``nav.recovery.ladder`` (a :class:`~curio.nav.recovery.Recovery` action, run as a task that
owns the wheels until it ends). Past the top rung it starts again from the bottom; after
``nav.recovery.max_rounds`` rounds it gives up with the error that got the rover stuck, noting
what was tried. Real progress (the distance remaining along the plan 1 m below where the
ladder was last climbed, :meth:`RecoveryLadder.note_progress`) starts the ladder afresh.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Coroutine
from dataclasses import dataclass
from typing import Any, Protocol

from curio.core.config import RecoveryConfig
from curio.nav.api import NavError
from curio.nav.costs import CostGrid
from curio.nav.recovery import RecoveryOutcome

__all__ = ["GiveUp", "RecoveryActions", "RecoveryLadder"]


class RecoveryActions(Protocol):
    """What the ladder needs from the recovery actions (:class:`curio.nav.recovery.Recovery`
    implements it)."""

    costmap: CostGrid | None

    def run(self, step: str) -> Coroutine[Any, Any, RecoveryOutcome]:
        """Run one ladder step (cancellable; it stops the rover)."""
        ...

    def clear_costmap(self) -> RecoveryOutcome:
        """Forget the obstacle marks around the rover."""
        ...


@dataclass(frozen=True)
class GiveUp:
    """The ladder is exhausted (or empty): abort the goal with ``error``; ``note`` says why."""

    error: NavError
    note: str


class RecoveryLadder:
    """The rungs, the rounds and the running recovery action (see the module docstring).

    Args:
        cfg: ``nav.recovery`` (``ladder``, ``max_rounds``).
        recovery: runs the actions; None gives up at once when stuck.
        fresh_start_m: this much real progress (metres along the plan) starts the ladder
            afresh.
    """

    def __init__(self, cfg: RecoveryConfig, recovery: RecoveryActions | None,
                 fresh_start_m: float = 1.0) -> None:
        self.cfg = cfg
        self.recovery = recovery
        self.fresh_start_m = fresh_start_m
        self.rung = 0
        self.rounds = 0
        self._climbed_at_m = math.inf
        self._task: asyncio.Future[RecoveryOutcome] | None = None

    def reset(self) -> None:
        """A new goal: the bottom rung, no round climbed (a running action is cancelled by
        :meth:`cancel`)."""
        self.rung = 0
        self.rounds = 0
        self._climbed_at_m = math.inf

    @property
    def busy(self) -> bool:
        """Whether an action was started and has not been collected yet."""
        return self._task is not None

    def collect(self) -> bool:
        """Whether the running action has finished (then it is forgotten)."""
        if self._task is None or not self._task.done():
            return False
        self._task = None
        return True

    def cancel(self) -> None:
        """Cancel the running action (it stops the rover)."""
        if self._task is not None:
            self._task.cancel()
            self._task = None

    def note_progress(self, remaining_m: float) -> None:
        """The rover got closer (``remaining_m`` along the plan): start afresh when that is
        ``fresh_start_m`` below where the ladder was last climbed (not just driving back to
        where it got stuck after a step back)."""
        if remaining_m < self._climbed_at_m - self.fresh_start_m:
            self.rung = 0
            self._climbed_at_m = remaining_m

    def climb(self, err: NavError, remaining_m: float) -> str | GiveUp:
        """The rover is stuck with ``err``, ``remaining_m`` (the best distance remaining)
        from the goal: start the next action and return its name, or give up."""
        ladder = list(self.cfg.ladder)
        if self.recovery is None or not ladder:
            return GiveUp(err, "stuck, no recovery configured")
        if self.rung >= len(ladder):
            self.rounds += 1
            self.rung = 0
            if self.rounds >= self.cfg.max_rounds:
                return GiveUp(type(err)(f"{err} (after recovery: {', '.join(ladder)})"),
                              "recovery exhausted")
        step = ladder[self.rung]
        self.rung += 1
        self._climbed_at_m = remaining_m
        self._task = asyncio.ensure_future(self.recovery.run(step))
        return step

    def clear_under_rover(self) -> None:
        """Forget the obstacle marks around the rover at once (the planner found its start
        blocked by them), before the ladder is climbed."""
        if self.recovery is not None and self.recovery.costmap is not None:
            self.recovery.clear_costmap()
