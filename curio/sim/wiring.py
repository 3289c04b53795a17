"""Simulator wiring: the world, rover physics and simulated sensors (owner: simulator)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from curio.app import App


def build_sim(app: App) -> None:
    """Construct this subsystem's parts from ``app.cfg`` and register them on ``app``."""
