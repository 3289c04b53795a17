"""The composition root: builds every part from the config and runs them in one task group.

Each subsystem has one wiring function that constructs its parts by constructor injection and
registers them here (``curio/sim/wiring.py``, ``curio/drivers/wiring.py``,
``curio/estimation/wiring.py``, ``curio/nav/wiring.py``, ``curio/bt/wiring.py``,
``curio/web/wiring.py``). The order of the calls below is the order of dependencies. Nothing
is a module-level singleton: two ``App`` objects can run side by side (tests do).

Shutdown order: the rover is stopped first (a zero velocity goes to the base and the base's
``halt()`` is awaited), then every task is cancelled and each part's ``close()`` runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, make_bus

__all__ = ["App", "Part"]

log = logging.getLogger("curio.app")


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


class App:
    """Everything that runs on the rover (or in the simulator), wired together.

    The attributes below are set by the subsystems' wiring functions; ``None`` means that part
    is not configured (e.g. ``world`` on the real rover).
    """

    def __init__(self, cfg: Config, clock: Clock, *, web: bool | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.bus: Bus = make_bus()
        self.parts: list[Part] = []
        self.halt_hooks: list[Callable[[], Awaitable[None]]] = []
        # Simulator (curio/sim/wiring.py)
        self.world: Any = None
        self.simulator: Any = None
        # Drivers (curio/drivers/wiring.py)
        self.base: Any = None
        self.lidar: Any = None
        self.imu: Any = None
        self.emulators: list[Any] = []
        # Estimation (curio/estimation/wiring.py)
        self.map_server: Any = None
        self.ekf: Any = None
        self.localizer: Any = None
        # Navigation (curio/nav/wiring.py)
        self.costmap: Any = None
        self.planner: Any = None
        self.controller: Any = None
        self.navigator: Any = None
        self.safety: Any = None
        self.obstacles: Any = None
        self.blocked: Any = None
        # Behaviour (curio/bt/wiring.py)
        self.paths: Any = None
        self.tree: Any = None
        # Web (curio/web/wiring.py)
        self.web: Any = None
        self.web_url: str | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._build(web)

    def _build(self, web: bool | None) -> None:
        from curio.bt.wiring import build_behaviour
        from curio.drivers.wiring import build_drivers
        from curio.estimation.wiring import build_estimation
        from curio.nav.wiring import build_navigation
        from curio.sim.wiring import build_sim

        build_sim(self)
        build_drivers(self)
        build_estimation(self)
        build_navigation(self)
        build_behaviour(self)
        if self.cfg.web.enabled if web is None else web:
            from curio.web.wiring import build_web

            build_web(self)

    def add(self, part: Part) -> None:
        """Register a part (wiring functions call this)."""
        self.parts.append(part)

    def add_halt_hook(self, hook: Callable[[], Awaitable[None]]) -> None:
        """Register a coroutine that stops the motors (run first at shutdown)."""
        self.halt_hooks.append(hook)

    async def start(self) -> None:
        """Start every part's task; return at once."""
        self.bus.bind_loop(asyncio.get_running_loop())
        for part in self.parts:
            if part.run is not None:
                task = asyncio.create_task(self._guard(part), name=part.name)
                self._tasks.append(task)

    async def _guard(self, part: Part) -> None:
        assert part.run is not None
        try:
            await part.run()
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("part %s crashed; stopping the rover", part.name)
            await self.halt()
            raise

    async def halt(self) -> None:
        """Stop the rover now: zero velocity to the base and every halt hook."""
        self.bus.publish(CMD_VEL, Twist(self.clock.now(), 0.0, 0.0, source="halt"))
        for hook in self.halt_hooks:
            with contextlib.suppress(Exception):
                await hook()

    async def stop(self) -> None:
        """Stop the rover, then cancel every task and close every part."""
        await self.halt()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._tasks.clear()
        for part in reversed(self.parts):
            if part.close is not None:
                with contextlib.suppress(Exception):
                    await part.close()

    def failed_parts(self) -> list[tuple[str, BaseException]]:
        """Parts whose task ended with an exception."""
        out = []
        for task in self._tasks:
            if task.done() and not task.cancelled() and task.exception() is not None:
                exc = task.exception()
                assert exc is not None
                out.append((task.get_name(), exc))
        return out
