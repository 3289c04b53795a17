"""The navigator (:class:`NavigatorNode`, :mod:`curio.nav.navigator.node`) and the policies
behind it, each a small class of its own module."""

from curio.nav.navigator.node import InvalidGoalError, NavigatorNode

__all__ = ["InvalidGoalError", "NavigatorNode"]
