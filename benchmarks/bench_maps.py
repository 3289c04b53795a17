"""Map switching benchmark: how long the rover is without its software when the active map
changes, and how long the safety stage takes to bring it to a standstill first.

``curio bench maps [--pairs N]``

``curio run``'s host (:class:`curio.commands.host.MapHost`) on the real clock, the simulated
rover in the default building, the dashboard serving: a second map (a copy of the building)
is added, and the rover switches between the two ``N`` times (default 6). Before each switch it
is driven forward by teleop at 0.25 m/s for 1.5 s and the joystick is held until the switch is
asked for. Row ``curio``: ``switches``; ``median_switch_s`` and ``max_switch_s`` (wall, from
the request to the new App serving: standstill, the old App stopped, the new one built and
started); ``median_standstill_s`` and ``max_standstill_s`` (until the safety stage's
``/cmd_vel`` is zero, at least 0.3 s); ``timeouts`` (switches where it was not zero within
``maps.stop_timeout_s`` and the App's halt stopped the base).
"""

from __future__ import annotations

import asyncio
import statistics
import tempfile
import time
from typing import Any

from curio.commands.bench import BenchOptions
from curio.commands.host import MapHost
from curio.core.clock import RealClock
from curio.core.config import REPO_ROOT, load_config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL_TELEOP


async def _switches(n: int, data_dir: str) -> list[tuple[float, float | None]]:
    cfg = load_config(REPO_ROOT / "config.toml", [
        f'data_dir="{data_dir}"', "web.enabled=true", "web.port=0", "bt.speak=false",
        "record.enabled=false"])
    clock = RealClock()
    host = MapHost(cfg, clock, web=True)
    await host.start()
    host.library.add("annex", host.library.grid(host.active), "1", "upload")
    stop = asyncio.Event()
    serve = asyncio.create_task(host.serve(stop))
    out: list[tuple[float, float | None]] = []
    try:
        await clock.sleep(3.0)
        for i in range(n):
            app = host.app
            assert app is not None
            held_until = clock.now() + 1.5
            async for t in clock.every(0.05):  # the joystick held forward
                app.bus.publish(CMD_VEL_TELEOP, Twist(t, 0.25, 0.0, source="bench"))
                if t >= held_until:
                    break
            gen = host.generation
            t0 = time.perf_counter()
            host.switch("annex" if i % 2 == 0 else "curio_building", "bench")
            while host.generation == gen or host.state()["switching"]:
                await clock.sleep(0.01)
            out.append((time.perf_counter() - t0, host.stand_still_s))
            await clock.sleep(1.0)
    finally:
        stop.set()
        await serve
        await host.stop()
    return out


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """The benchmark (see the module docstring)."""
    n = opts.pairs or 6
    with tempfile.TemporaryDirectory(prefix="curio-bench-maps-") as tmp:
        results = asyncio.run(_switches(n, tmp))
    totals = [r[0] for r in results]
    still = [r[1] for r in results if r[1] is not None]
    return [{
        "subject": "curio",
        "switches": len(results),
        "median_switch_s": round(statistics.median(totals), 3),
        "max_switch_s": round(max(totals), 3),
        "median_standstill_s": round(statistics.median(still), 3) if still else None,
        "max_standstill_s": round(max(still), 3) if still else None,
        "timeouts": len(results) - len(still),
    }]
