"""Navigation wiring: costmap, planner, controller, navigator, recovery, safety, blocked."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from curio.app import App


def build_navigation(app: App) -> None:
    """Construct this subsystem's parts from ``app.cfg`` and register them on ``app``."""
