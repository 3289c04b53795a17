"""CpuMeter: CPU time per task label, children charged to their part, the remainder."""

from __future__ import annotations

import asyncio

from curio.core.clock import SimClock, thread_cpu_time
from curio.core.cpu_meter import CpuMeter


def _spin(cpu_s: float) -> None:
    t0 = thread_cpu_time()
    while thread_cpu_time() - t0 < cpu_s:
        pass


async def _scene(meter: CpuMeter) -> None:
    meter.install()
    clock = SimClock()

    async def child() -> None:
        for _ in range(3):
            _spin(0.01)
            await clock.sleep(0.0)  # one turn of the loop

    async def part_a() -> None:
        for _ in range(5):
            _spin(0.01)
            await clock.sleep(0.0)  # one turn of the loop
        await asyncio.create_task(child())  # unnamed: charged to part_a

    async def part_b() -> None:
        await asyncio.create_task(child(), name="own-name")  # named: its own label

    await asyncio.gather(asyncio.create_task(part_a(), name="a"),
                         asyncio.create_task(part_b(), name="b"))
    _spin(0.02)  # in the unmetered main task: the remainder
    meter.uninstall()


def test_tasks_and_their_unnamed_children_are_charged_to_their_label() -> None:
    meter = CpuMeter()
    asyncio.run(_scene(meter))
    rep = meter.report()
    assert 0.075 <= meter.seconds["a"] < 0.2  # 5 + 3 spins of 10 ms
    assert 0.025 <= meter.seconds["own-name"] < 0.1
    assert meter.seconds.get("b", 0.0) < 0.01
    assert meter.steps["a"] >= 8
    assert rep["loop_s"] >= 0.018  # the main task's spin is nobody's
    assert abs(rep["process_s"] - sum(meter.seconds.values()) - rep["loop_s"]) < 1e-9


def test_only_the_chosen_labels_are_timed() -> None:
    meter = CpuMeter(only=("own",))
    asyncio.run(_scene(meter))
    assert set(meter.seconds) == {"own-name"}
    assert meter.report()["loop_s"] >= 0.09  # a's work is in the remainder now
