"""Power wiring: the power monitor as a part (it runs in every drivers mode)."""

from __future__ import annotations

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.parts import Part, Parts

from .monitor import PowerMonitor

__all__ = ["build_power"]


def build_power(cfg: Config, bus: Bus, clock: Clock, parts: Parts) -> PowerMonitor:
    """Build the power monitor and register it."""
    monitor = PowerMonitor(cfg, bus, clock)
    parts.add(Part("power", run=monitor.run))
    return monitor
