"""Guards: the conditions that open a branch of the priority selector (they never act).

``check_key`` is py_trees' own blackboard comparison in the tree's namespace; ``IsBlocked``
also asks the path follower whether a goal of ours is being driven or was given up.
"""

from __future__ import annotations

import operator

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import ComparisonExpression, Status

from .context import CurioBehaviour, TreeContext

__all__ = ["IsBlocked", "check_key"]


def check_key(ctx: TreeContext, name: str, key: str, value: object,
              op: object = operator.eq) -> Behaviour:
    """A blackboard condition (py_trees' own CheckBlackboardVariableValue)."""
    return py_trees.behaviours.CheckBlackboardVariableValue(
        name=name, check=ComparisonExpression(ctx.key(key), value, op))  # type: ignore[arg-type]


class IsBlocked(CurioBehaviour):
    """SUCCESS when the way is blocked and recovery has not freed it, and no re-arm delay runs.

    Blocked means: BLOCKED says blocked while a goal of ours is being driven, or the navigator
    gave the waypoint up because the way is blocked (no path, no progress, no admissible
    motion, after its recovery ladder). Never at a reached goal, never idle, never at start-up.
    """

    def __init__(self, ctx: TreeContext, name: str = "Blocked?") -> None:
        super().__init__(name, ctx, read=("blocked", "help_rearm_until"))

    def update(self) -> Status:
        """Check the flag and the follower."""
        f = self.ctx.follower
        if not ((self.get("blocked") and f.driving) or f.failed_blocked):
            return Status.FAILURE
        rearm = self.get("help_rearm_until")
        if rearm is not None and self.ctx.clock.now() < rearm:
            return Status.FAILURE
        return Status.SUCCESS
