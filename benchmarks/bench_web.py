"""Dashboard cost: 10 WebSocket clients at 10 Hz against the whole app on the real clock.

The subject is the complete application (simulator, estimation, navigation, behaviour tree,
dashboard) on :class:`~curio.core.clock.RealClock`, driving path 2, with the dashboard on a loopback
port. It runs twice for the same time: without clients, then with ``clients`` browsers'
worth of WebSocket connections (each asks for ``rate_hz`` streams and reads every frame; they
run in a separate process pinned to another core, so only the server's work is counted).

Figures per run:

* ``cpu_fraction`` — the app process's CPU seconds per wall second (1.0 = one core);
* ``p99_ms`` / ``max_ms`` — tick jitter of a 20 Hz loop on the app's event loop (the rate of
  the safety stage and controller): lateness of each tick against its due time, wall clock;
* ``frames_per_client_s`` / ``kbytes_per_client_s`` — what each client received.

Targets (issue 7): clients add ≤ 0.05 of one core, p99 jitter with clients ≤ 10 ms.
Options (``--set``): ``duration=20`` (seconds per run), ``clients=10``, ``rate_hz=10``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import multiprocessing as mp
import os
import tempfile
from typing import Any

import aiohttp
import numpy as np

from curio.app import App
from curio.commands.bench import BenchOptions
from curio.core.clock import RealClock, process_cpu_time, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.core.messages import OperatorCommand
from curio.core.topics import OPERATOR

TICK_HZ = 20.0


def _pin(core_index: int) -> None:
    if hasattr(os, "sched_setaffinity"):
        cores = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cores[core_index % len(cores)]})


async def _clients_main(url: str, n: int, rate_hz: float, duration_s: float) -> dict[str, float]:
    frames = [0] * n
    nbytes = [0] * n

    async def one(i: int, session: aiohttp.ClientSession) -> None:
        async with session.ws_connect(url + "ws") as ws:
            await ws.send_json({"op": "rate", "hz": rate_hz})
            async for msg in ws:
                frames[i] += 1
                nbytes[i] += len(msg.data) if isinstance(msg.data, bytes | str) else 0

    async with aiohttp.ClientSession() as session:
        tasks = [asyncio.create_task(one(i, session)) for i in range(n)]
        t0 = wall_perf_counter()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.gather(*tasks), timeout=duration_s)
        elapsed = wall_perf_counter() - t0
    return {"frames_per_client_s": sum(frames) / n / elapsed,
            "kbytes_per_client_s": sum(nbytes) / n / elapsed / 1000.0}


def _clients_process(url: str, n: int, rate_hz: float, duration_s: float, out: Any) -> None:
    _pin(1)
    out.put(asyncio.run(_clients_main(url, n, rate_hz, duration_s)))


async def _run_app(n_clients: int, rate_hz: float, duration_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(REPO_ROOT / "config.toml",
                          [f'data_dir="{tmp}"', "web.port=0", "bt.speak=false"])
        clock = RealClock()
        app = App(cfg, clock, web=True)
        await app.start()
        try:
            await clock.sleep(2.0)  # start-up settles
            app.bus.publish(OPERATOR, OperatorCommand(clock.now(), "select_path", path_id=2,
                                                      source="bench"))
            result_q: Any = None
            proc = None
            if n_clients:
                ctx = mp.get_context("spawn")
                result_q = ctx.Queue()
                proc = ctx.Process(target=_clients_process,
                                   args=(app.web.url, n_clients, rate_hz, duration_s + 8.0,
                                         result_q))
                proc.start()
                await clock.sleep(2.0)  # clients connected and receiving
            lateness: list[float] = []
            period = 1.0 / TICK_HZ
            cpu0, wall0 = process_cpu_time(), wall_perf_counter()
            due = wall0 + period
            while wall_perf_counter() - wall0 < duration_s:
                await clock.sleep(max(0.0, due - wall_perf_counter()))
                lateness.append(max(0.0, wall_perf_counter() - due))
                due += period
            cpu, wall = process_cpu_time() - cpu0, wall_perf_counter() - wall0
            clients = len(app.web.hub.clients)
            row: dict[str, Any] = {}
            if proc is not None and result_q is not None:
                row.update(await asyncio.to_thread(result_q.get, True, 30.0))
                await asyncio.to_thread(proc.join, 10.0)
        finally:
            await app.stop()
    lat_ms = np.array(lateness) * 1000.0
    return {"cpu_fraction": round(cpu / wall, 4),
            "p99_ms": round(float(np.percentile(lat_ms, 99)), 2),
            "max_ms": round(float(lat_ms.max()), 2),
            "median_ms": round(float(np.median(lat_ms)), 3),
            "ticks": len(lateness), "clients_seen": clients, **row}


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run without and with clients; return both rows and their difference."""
    _pin(0)
    duration_s = float(opts.extra.get("duration", 20))
    n = int(opts.extra.get("clients", 10))
    rate_hz = float(opts.extra.get("rate_hz", 10))
    base = asyncio.run(_run_app(0, rate_hz, duration_s))
    loaded = asyncio.run(_run_app(n, rate_hz, duration_s))
    rows = [
        {"subject": "curio, no dashboard clients", **base},
        {"subject": f"curio, {n} clients at {rate_hz:g} Hz", **loaded},
        {"subject": "difference (clients - none)",
         "cpu_fraction": round(loaded["cpu_fraction"] - base["cpu_fraction"], 4),
         "p99_ms": round(loaded["p99_ms"] - base["p99_ms"], 2),
         "max_ms": round(loaded["max_ms"] - base["max_ms"], 2),
         "target": "cpu_fraction <= 0.05, p99_ms with clients <= 10",
         "met": bool(loaded["cpu_fraction"] - base["cpu_fraction"] <= 0.05
                     and loaded["p99_ms"] <= 10.0)},
    ]
    return rows


if __name__ == "__main__":  # pragma: no cover - manual use
    print(json.dumps(run(BenchOptions()), indent=2))
