"""Safety wiring: the safety stage as a part, and its halt hook.

``build_safety`` always runs: the stage is the only publisher of ``/cmd_vel`` (DESIGN rule 6),
in every drivers mode.
"""

from __future__ import annotations

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import Twist
from curio.core.parts import Part, Parts
from curio.core.topics import CMD_VEL
from curio.robot import RobotModel
from curio.safety.stage import SafetyStage

__all__ = ["build_safety"]


def build_safety(cfg: Config, bus: Bus, clock: Clock, parts: Parts,
                 robot: RobotModel) -> SafetyStage:
    """Build the safety stage from ``nav.safety`` and register its part and halt hook."""
    stage = SafetyStage(cfg.nav.safety, robot, clock, bus)

    async def halt() -> None:
        bus.publish(CMD_VEL, Twist(clock.now(), 0.0, 0.0, source="safety:halt"))

    parts.add(Part("safety", run=stage.run))
    parts.add_halt_hook(halt)
    return stage
