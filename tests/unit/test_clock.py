"""The simulated clock: ordering, determinism, rate loops, timeouts, speed pacing."""

from __future__ import annotations

import asyncio

import pytest

from curio.core.clock import RateStats, RealClock, SimClock, wall_perf_counter


async def test_timers_fire_in_time_then_registration_order() -> None:
    clock = SimClock()
    log: list[tuple[str, float]] = []

    async def sleeper(name: str, delays: list[float]) -> None:
        for d in delays:
            await clock.sleep(d)
            log.append((name, round(clock.now(), 6)))

    tasks = [
        asyncio.create_task(sleeper("a", [0.3, 0.3])),
        asyncio.create_task(sleeper("b", [0.1, 0.5])),
        asyncio.create_task(sleeper("c", [0.6])),
    ]
    await clock.run(until_s=1.0)
    assert all(t.done() for t in tasks)
    # a and b both wake at 0.6: b registered its 0.6 timer at t=0.1, a at t=0.3, c at t=0.
    assert log == [("b", 0.1), ("a", 0.3), ("c", 0.6), ("b", 0.6), ("a", 0.6)]
    assert clock.now() == pytest.approx(1.0)


async def test_same_program_gives_same_trace_twice() -> None:
    async def program() -> list[tuple[int, float]]:
        clock = SimClock()
        trace: list[tuple[int, float]] = []

        async def worker(i: int) -> None:
            async for t in clock.every(0.01 * (i + 1)):
                trace.append((i, round(t, 9)))

        tasks = [asyncio.create_task(worker(i)) for i in range(5)]
        await clock.run(until_s=2.0)
        for t in tasks:
            t.cancel()
        return trace

    first, second = await program(), await program()
    assert len(first) > 400
    assert first == second


async def test_every_does_not_drift_and_counts_overruns() -> None:
    clock = SimClock()
    stamps: list[float] = []
    stats = RateStats()

    async def loop() -> None:
        async for t in clock.every(0.1, stats):
            stamps.append(t)
            if len(stamps) == 5:
                await clock.sleep(0.35)  # one slow iteration: later ones skip ahead

    task = asyncio.create_task(loop())
    await clock.run(until_s=1.0)
    task.cancel()
    assert stamps[:5] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    assert stats.overruns == 1
    # After the overrun the loop keeps the original phase (multiples of 0.1).
    assert all(abs(t * 10 - round(t * 10)) < 1e-9 for t in stamps)


async def test_every_immediate_runs_its_first_iteration_before_any_other_task() -> None:
    clock = SimClock()
    order: list[str] = []

    async def loop(name: str, immediate: bool) -> None:
        async for t in clock.every(0.25, immediate=immediate):
            order.append(f"{name}@{t}")

    async def other() -> None:
        order.append("other")

    async def start(immediate: bool) -> list[str]:
        order.clear()
        tasks = [asyncio.create_task(loop("loop", immediate))]
        tasks.append(asyncio.create_task(other()))
        await clock.advance(0.5)
        for t in tasks:
            t.cancel()
        return list(order)

    # Plain, the loop waits for its first due time (now) like any sleep: others go first.
    assert (await start(False))[:2] == ["other", "loop@0.0"]
    # Immediate, it runs at once; then every period from there.
    assert await start(True) == ["loop@0.5", "other", "loop@0.75", "loop@1.0"]


async def test_wait_for_times_out_in_simulated_time() -> None:
    clock = SimClock()

    async def slow() -> int:
        await clock.sleep(10.0)
        return 1

    async def fast() -> int:
        await clock.sleep(1.0)
        return 2

    async def body() -> tuple[object, int]:
        try:
            await clock.wait_for(slow(), 2.0)
            outcome: object = "finished"
        except TimeoutError:
            outcome = ("timeout", clock.now())
        return outcome, await clock.wait_for(fast(), 2.0)

    task = asyncio.create_task(body())
    start = wall_perf_counter()
    await clock.run(stop=task.done)
    outcome, value = task.result()
    assert outcome == ("timeout", 2.0)
    assert value == 2
    assert wall_perf_counter() - start < 1.0  # 3 simulated seconds take no wall time


async def test_speed_runs_at_a_multiple_of_real_time() -> None:
    clock = SimClock(speed=20.0)

    async def sleeper() -> None:
        await clock.sleep(2.0)

    task = asyncio.create_task(sleeper())
    start = wall_perf_counter()
    await clock.run(stop=task.done)
    elapsed = wall_perf_counter() - start
    assert 0.08 <= elapsed < 0.5  # 2 s at 20x = 0.1 s of wall time


async def test_real_clock_sleeps_real_time() -> None:
    clock = RealClock()
    t0 = clock.now()
    await clock.sleep(0.02)
    assert clock.now() - t0 >= 0.015


def test_sim_clock_rejects_bad_speed() -> None:
    with pytest.raises(ValueError, match="speed"):
        SimClock(speed=0)
