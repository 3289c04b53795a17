"""Closing the Arduino link: :meth:`ArduinoBase.close` stops the wheels, closes the port and
returns only once the OS has released it (the driver opens the port exclusively), however
abruptly the driver was stopped; and in emulated mode the port's open and close, which run in
a worker thread, take no simulated time.

Real pty I/O against the byte-exact emulator; real time except for the last test.
"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
import serial
import serial_asyncio_fast

from curio.core.clock import RealClock, SimClock, wall_sleep
from curio.core.config import ArduinoConfig, RobotConfig
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, make_bus
from curio.drivers.arduino import ArduinoBase, ArduinoEmulator
from curio.drivers.arduino import protocol as p
from curio.robot import RobotModel
from tests.integration.test_arduino_emulator import FAST, make_rig
from tests.integration.test_arduino_fakes import FakeWorld


def _take_port_exclusively(path: str) -> None:
    """Open and close ``path`` as the driver does (exclusive lock); raises if it is held."""
    port = serial.Serial(path, 115200, exclusive=True)
    port.close()


async def test_close_after_abrupt_cancel_frees_the_port_at_once() -> None:
    async with make_rig() as rig:
        assert rig.base_task is not None
        rig.base_task.cancel()  # the app dies abruptly: no halt() first
        await asyncio.gather(rig.base_task, return_exceptions=True)
        await rig.base.close()
        _take_port_exclusively(rig.emu.port_path)  # at once: no "could not exclusively lock"
        assert not rig.base.connected
        # A new driver on the same port connects, configures and drives again.
        again = ArduinoBase(FAST, RobotModel.from_config(RobotConfig()), rig.bus, rig.clock,
                            port=rig.emu.port_path)
        task = asyncio.ensure_future(again.run())
        try:
            await rig.until(rig.driving, 3.0)
            assert again.health().state == "ok"
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await again.close()
        _take_port_exclusively(rig.emu.port_path)


async def test_abrupt_cancel_stops_and_disarms_the_board() -> None:
    async with make_rig() as rig:
        assert rig.base_task is not None and rig.driving()
        rig.base_task.cancel()
        await asyncio.gather(rig.base_task, return_exceptions=True)
        await rig.base.close()
        # The board's own watchdogs would give TIMEOUT after 0.3 s and DISARMED only after
        # 2 s without frames: DISARMED within 1 s means the driver's stop got through.
        await rig.until(lambda: rig.stopped() and rig.emu.state == p.McuState.DISARMED
                        and rig.world.duties == (0,) * 6, 1.0)


async def test_close_while_running_ends_run_and_frees_the_port() -> None:
    async with make_rig() as rig:
        assert rig.base_task is not None
        await rig.base.close()
        await rig.until(rig.base_task.done, 1.0)  # run() returned instead of reconnecting
        assert rig.base_task.exception() is None
        _take_port_exclusively(rig.emu.port_path)
        assert rig.base.health().counters["reconnects"] == 0
        await rig.until(lambda: rig.stopped() and rig.emu.state == p.McuState.DISARMED, 1.0)


async def test_cancel_while_the_port_opens_then_close_frees_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The open runs in a worker thread that a cancel cannot stop: close() waits for it and
    closes the port it opened."""
    real_open = serial_asyncio_fast.open_serial_connection
    opened = asyncio.Event()

    async def slow_open(**kwargs: Any) -> Any:
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(None, wall_sleep, 0.05)  # a slow USB enumeration
        got = await real_open(**kwargs)
        opened.set()
        return got

    clock = RealClock()
    emu = ArduinoEmulator(FakeWorld(), clock, boot_delay_s=0.1)
    emu.open()
    base = ArduinoBase(FAST, RobotModel.from_config(RobotConfig()), make_bus(), clock,
                       port=emu.port_path)
    try:
        monkeypatch.setattr(serial_asyncio_fast, "open_serial_connection", slow_open)
        task = asyncio.ensure_future(base.run())
        await clock.sleep(0.01)
        assert not opened.is_set()  # still opening
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await base.close()
        assert opened.is_set()
        _take_port_exclusively(emu.port_path)
    finally:
        emu.close()


async def test_paced_driver_holds_the_sim_clock_while_the_port_opens_and_closes(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Emulated mode: port work in a worker thread (made slow here: 50 ms of wall time each
    way) takes no simulated time, so how long the thread takes cannot change a run."""
    real_open = serial_asyncio_fast.open_serial_connection
    open_span_s: list[tuple[float, float]] = []
    clock = SimClock(settle_polls=3)

    async def slow_open(**kwargs: Any) -> Any:
        start_s = clock.now()
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(None, wall_sleep, 0.05)
        reader, writer = await real_open(**kwargs)
        open_span_s.append((start_s, clock.now()))
        ser = writer.transport.serial  # the close, too, becomes slow

        def slow_close(real_close: Any = ser.close) -> None:
            wall_sleep(0.05)
            real_close()

        ser.close = slow_close
        return reader, writer

    monkeypatch.setattr(serial_asyncio_fast, "open_serial_connection", slow_open)
    bus = make_bus()
    bus.bind_loop(asyncio.get_running_loop())
    emu = ArduinoEmulator(FakeWorld(), clock, seed=1)
    emu.open()
    base = ArduinoBase(ArduinoConfig(), RobotModel.from_config(RobotConfig()), bus, clock,
                       port=emu.port_path)
    emu.pair(base)
    close_span_s: list[tuple[float, float]] = []

    async def command_then_close() -> None:
        while clock.now() < 3.0:
            bus.publish(CMD_VEL, Twist(stamp=clock.now(), linear_mps=0.2))
            await clock.sleep(0.05)
        start_s = clock.now()
        await base.close()
        close_span_s.append((start_s, clock.now()))

    tasks = [asyncio.ensure_future(c) for c in (emu.run(), base.run(), command_then_close())]
    try:
        await clock.run(until_s=4.0)
        assert len(open_span_s) == 1 and open_span_s[0][0] == open_span_s[0][1], open_span_s
        assert len(close_span_s) == 1 and close_span_s[0][0] == close_span_s[0][1], close_span_s
        assert emu.boots == 1 and base.counters["reconnects"] == 0
        assert tasks[1].done()  # run() ended with close()
        _take_port_exclusively(emu.port_path)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await base.close()
        emu.close()
