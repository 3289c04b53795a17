"""What the map library's tests share: ``curio run``'s host (MapHost) with the real App on a
real-time SimClock, serving the dashboard, and the host's change loop running."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

from curio.commands.host import MapHost
from curio.core.clock import SimClock
from curio.core.config import Config


@contextlib.asynccontextmanager
async def hosted(cfg: Config, speed: float = 3.0) -> AsyncIterator[tuple[MapHost, str]]:
    """The host started on ``cfg`` and the dashboard's base URL (no trailing slash); the
    last App must have no crashed part."""
    clock = SimClock(speed=speed, epoch_wall_s=1_700_000_000.0)
    host = MapHost(cfg, clock, web=True)
    app = await host.start()
    runner = asyncio.create_task(clock.run())
    stop = asyncio.Event()
    serve = asyncio.create_task(host.serve(stop))
    try:
        yield host, (app.web_url or "").split("?")[0].rstrip("/")
        assert host.app is not None and host.app.failed_parts() == []
    finally:
        stop.set()
        await serve
        await host.stop()
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner
