"""Navigation wiring: costmap, planner, controller, navigator, recovery, safety, blocked.

``build_navigation(app)`` constructs the navigation parts from ``app.cfg`` and registers them on
``app``. The safety stage is always built: it is the only publisher of ``/cmd_vel``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from curio.nav.safety import register_safety

if TYPE_CHECKING:
    from curio.app import App


def build_navigation(app: App) -> None:
    """Construct this subsystem's parts from ``app.cfg`` and register them on ``app``."""
    register_safety(app)
