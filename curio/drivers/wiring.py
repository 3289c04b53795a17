"""Driver wiring: odometry in every mode; device drivers and emulators when not in sim mode."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from curio.app import App


def build_drivers(app: App) -> None:
    """Construct this subsystem's parts from ``app.cfg`` and register them on ``app``."""
