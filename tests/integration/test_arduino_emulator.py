"""The real driver against the byte-exact emulator over a pseudo-terminal, with every fault knob.

Real time (pty I/O is real), short timeouts: each test takes one or two seconds.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import pytest

from curio.core.bus import Bus
from curio.core.clock import RealClock
from curio.core.config import ArduinoConfig, RobotConfig
from curio.core.messages import EStop, Twist
from curio.core.topics import (
    BATTERY,
    CMD_VEL,
    ESTOP,
    EVENTS,
    HEALTH,
    SERVO_CMD,
    WHEELS,
    make_bus,
)
from curio.drivers.arduino import ArduinoBase, ArduinoEmulator
from curio.drivers.arduino import protocol as p
from curio.robot import RobotModel
from tests.integration.test_arduino_fakes import FakeWorld

# Short timeouts, with margins for a loaded CI machine (the loop may stall ~100 ms).
FAST = ArduinoConfig(boot_wait_s=1.0, link_timeout_s=0.5, mcu_cmd_timeout_s=0.3,
                     reconnect_max_s=0.2, cmd_rate_hz=25, cmd_timeout_s=0.3)


@dataclass
class Rig:
    clock: RealClock
    bus: Bus
    world: FakeWorld
    emu: ArduinoEmulator
    base: ArduinoBase
    speed_mps: float = 0.2
    publishing: bool = True
    base_task: asyncio.Future[None] | None = None  # base.run()

    async def until(self, pred: Callable[[], bool], timeout_s: float = 3.0) -> None:
        ok = await self.clock.wait_until(pred, timeout_s, poll_s=0.01)
        assert ok, f"timed out; health: {self.base.health()}"

    def driving(self) -> bool:
        return self.emu.state == p.McuState.ARMED and all(self.emu.wheel_duties)

    def stopped(self) -> bool:
        return not any(self.emu.wheel_duties)


async def _commander(rig: Rig) -> None:
    while True:
        if rig.publishing:
            rig.bus.publish(CMD_VEL, Twist(stamp=rig.clock.now(), linear_mps=rig.speed_mps))
        await rig.clock.sleep(0.04)


@contextlib.asynccontextmanager
async def make_rig(cfg: ArduinoConfig = FAST, boot_delay_s: float = 0.1) -> AsyncIterator[Rig]:
    clock = RealClock()
    bus = make_bus()
    bus.bind_loop(asyncio.get_running_loop())
    world = FakeWorld()
    emu = ArduinoEmulator(world, clock, boot_delay_s=boot_delay_s, seed=3)
    emu.open()
    base = ArduinoBase(cfg, RobotModel.from_config(RobotConfig()), bus, clock, port=emu.port_path)
    rig = Rig(clock, bus, world, emu, base)
    tasks = [asyncio.ensure_future(emu.run()), asyncio.ensure_future(base.run()),
             asyncio.ensure_future(_commander(rig))]
    rig.base_task = tasks[1]
    try:
        await rig.until(rig.driving)
        yield rig
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await base.close()
        emu.close()


async def test_arm_command_feedback_battery() -> None:
    async with make_rig() as rig:
        wheels = rig.bus.subscribe(WHEELS, maxsize=100)
        battery = rig.bus.subscribe(BATTERY)
        sent = rig.bus.subscribe(SERVO_CMD)
        await rig.clock.sleep(1.1)
        # 0.2 m/s straight: the duties of hardware.md §2.2's first test vector.
        assert rig.emu.wheel_duties == (530, 530, 530, -530, -530, -530)
        assert rig.world.steer == (500, 500, 500, 500)
        readings = wheels.drain()
        assert len(readings) >= 20  # about 30 Hz
        first, last = readings[0].positions, readings[-1].positions
        assert first[0] is not None and last[0] is not None and first[0] != last[0]
        assert [r.positions for r in readings[-3:]] != [readings[-1].positions] * 3
        msg = battery.get_nowait()
        assert msg is not None and msg.voltage_v == pytest.approx(7.4) and not msg.low
        cmd = sent.get_nowait()
        assert cmd is not None and cmd.wheel_duty[0] == 530
        h = rig.base.health()
        assert h.state == "ok", h
        assert h.counters["crc_errors"] == 0 and h.counters["reconnects"] == 0
        assert rig.base.info is not None and rig.base.info.proto_ver == p.PROTO_VERSION


async def test_stale_cmd_vel_stops_wheels_but_stays_armed() -> None:
    async with make_rig() as rig:
        rig.publishing = False
        await rig.until(rig.stopped, 2.0)
        assert rig.emu.state == p.McuState.ARMED  # the driver sends zero commands
        rig.publishing = True
        await rig.until(rig.driving, 2.0)


async def test_unplug_stops_rover_and_driver_reconnects() -> None:
    async with make_rig() as rig:
        rig.emu.unplug()
        await rig.until(rig.stopped, 2.0)  # the board's own watchdog
        assert rig.emu.firmware.state == p.McuState.TIMEOUT
        await rig.until(lambda: rig.base.health().state == "error", 2.0)
        assert "link down" in rig.base.health().message
        await rig.clock.sleep(0.4)
        rig.emu.replug()
        await rig.until(rig.driving, 3.0)
        h = rig.base.health()
        assert h.counters["reconnects"] >= 1 and h.counters["link_losses"] >= 1
        assert rig.emu.boots == 2  # opening the port reset the board (DTR)
        assert h.state == "ok" and "recovered from" in h.message


async def test_garbage_bytes_resync_without_stopping() -> None:
    async with make_rig() as rig:
        rig.base.rx_error_window_s = 0.5
        for _ in range(5):
            rig.emu.inject_garbage(97)
            await rig.clock.sleep(0.05)
        h = rig.base.health()
        assert h.counters["resyncs"] >= 1 and h.counters["garbage_bytes"] >= 97
        assert h.state == "degraded" and "corrupt data from the Mega" in h.message, h
        assert "garbage bytes" in h.message and "USB cable" in h.message
        assert rig.driving()  # frames still get through: no reason to stop
        await rig.until(lambda: rig.driving() and rig.base.health().state == "ok", 2.0)


async def test_crc_errors_and_truncated_frames_from_board() -> None:
    async with make_rig() as rig:
        rig.emu.corrupt_tx(5)
        rig.emu.truncate_tx(3)
        await rig.clock.sleep(0.4)
        h = rig.base.health()
        assert h.counters["crc_errors"] >= 5
        assert h.state == "degraded" and "CRC errors" in h.message, h
        await rig.until(rig.driving, 2.0)


async def test_corrupted_commands_trip_firmware_watchdog_then_recover() -> None:
    async with make_rig() as rig:
        rig.emu.corrupt_rx(0.8)
        await rig.until(rig.stopped, 2.0)
        assert rig.emu.firmware.state == p.McuState.TIMEOUT
        await rig.until(lambda: rig.base.mcu_state == p.McuState.TIMEOUT, 2.0)
        h = rig.base.health()
        assert h.state == "degraded" and "watchdog stopped the wheels" in h.message
        assert h.counters["mcu_rx_crc_err"] >= 1
        await rig.until(rig.driving, 2.0)  # the next good SERVO_CMD resumes, no re-arm needed
        assert rig.base.health().counters["watchdog_trips"] >= 1


async def test_board_reset_reconfigures_and_rearms() -> None:
    cfg = FAST.model_copy(update={"link_timeout_s": 0.8})
    async with make_rig(cfg) as rig:
        health = rig.bus.subscribe(HEALTH, maxsize=1000)
        events = rig.bus.subscribe(EVENTS)
        rig.emu.reset()
        assert rig.stopped() and rig.emu.state == p.McuState.BOOT  # wheels stop at once
        await rig.until(lambda: rig.emu.boots == 2, 2.0)
        await rig.until(rig.driving, 2.0)
        assert not rig.emu.firmware.faults & p.Fault.DEFAULT_CONFIG  # config re-sent
        assert rig.base.health().counters["mcu_resets"] >= 1
        # Found by curio soak: the reset (and the silent boot window) never showed in
        # /health, so the event log had no trace of it.
        states = [h for h in health.drain() if h.name == "arduino"]
        assert any(h.state == "degraded" for h in states), [h.message for h in states]
        assert states[-1].state == "ok"
        assert "driver.arduino_reset" in [e.kind for e in events.drain()]


async def test_no_bytes_streamed_into_the_bootloader() -> None:
    cfg = FAST.model_copy(update={"link_timeout_s": 2.5})
    async with make_rig(cfg, boot_delay_s=0.1) as rig:
        rig.emu.boot_delay_s = 1.5  # a slow bootloader after a spontaneous reset
        rig.emu.reset()
        await rig.clock.sleep(0.3)  # the driver notices the silence within 0.15 s
        held_at = rig.emu.bytes_in
        await rig.clock.sleep(0.4)
        assert rig.emu.state == p.McuState.BOOT
        assert rig.emu.bytes_in == held_at  # nothing sent while the board is quiet
        assert rig.base.health().counters["tx_holds"] >= 1
        await rig.until(rig.driving, 3.0)  # then it re-configures, re-arms and drives
        assert rig.base.health().counters["mcu_resets"] >= 1
        assert rig.base.health().counters["link_losses"] == 0


async def test_stall_stops_rover_and_driver_reconnects() -> None:
    async with make_rig() as rig:
        rig.emu.stall(1.2)
        await rig.until(rig.stopped, 2.0)
        await rig.until(lambda: rig.base.health().counters["link_losses"] >= 1, 2.0)
        assert "no frame from the Mega" in rig.base.last_error
        await rig.until(rig.driving, 3.0)
        assert rig.base.health().counters["reconnects"] >= 1


async def test_servo_read_failures_reported() -> None:
    async with make_rig() as rig:
        wheels = rig.bus.subscribe(WHEELS)
        rig.emu.servo_read_fail_rate = 1.0
        await rig.clock.sleep(0.2)
        msg = wheels.get_nowait()
        assert msg is not None and all(pos is None for pos in msg.positions)
        h = rig.base.health()
        assert h.state == "degraded" and "servo did not answer" in h.message
        assert h.counters["servo_read_failures"] >= 1


async def test_estop_latches_on_board_and_releases() -> None:
    async with make_rig() as rig:
        rig.bus.publish(ESTOP, EStop(stamp=rig.clock.now(), engaged=True, source="test"))
        await rig.until(lambda: rig.emu.state == p.McuState.ESTOP and rig.stopped(), 2.0)
        await rig.clock.sleep(0.2)
        assert rig.stopped()
        assert "e-stop" in rig.base.health().message
        rig.bus.publish(ESTOP, EStop(stamp=rig.clock.now(), engaged=False, source="test"))
        await rig.until(rig.driving, 2.0)


async def test_halt_stops_and_disarms() -> None:
    async with make_rig() as rig:
        health = rig.bus.subscribe(HEALTH, maxsize=50)
        await rig.base.halt()
        await rig.until(lambda: rig.stopped() and rig.emu.state == p.McuState.DISARMED, 2.0)
        await rig.clock.sleep(0.2)
        assert rig.stopped() and rig.emu.state == p.McuState.DISARMED  # no re-arm after halt
        assert rig.base.health().state == "off"
        assert any(h.name == "arduino" for h in health.drain())


async def test_missing_port_says_what_to_check() -> None:
    clock = RealClock()
    bus = make_bus()
    base = ArduinoBase(FAST, RobotModel.from_config(RobotConfig()), bus, clock,
                       port="/nonexistent/curio-arduino")
    task = asyncio.ensure_future(base.run())
    try:
        await clock.wait_until(lambda: base.health().state == "error", 1.0, poll_s=0.01)
        h = base.health()
        assert h.state == "error"
        assert "/nonexistent/curio-arduino" in h.message and "curio check" in h.message
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


async def test_emulated_mode_on_a_simulated_clock() -> None:
    """As ``drivers.mode = "emulated"`` runs it: virtual time as fast as the CPU allows, real
    pty I/O in between (the clock grants a few idle I/O polls before moving time on)."""
    from curio.core.clock import SimClock

    clock = SimClock(settle_polls=3)
    bus = make_bus()
    bus.bind_loop(asyncio.get_running_loop())
    world = FakeWorld()
    emu = ArduinoEmulator(world, clock, seed=1)
    emu.open()
    base = ArduinoBase(ArduinoConfig(), RobotModel.from_config(RobotConfig()), bus, clock,
                       port=emu.port_path)
    emu.pair(base)
    wheels = bus.subscribe(WHEELS, maxsize=1000)

    async def command() -> None:
        while True:
            bus.publish(CMD_VEL, Twist(stamp=clock.now(), linear_mps=0.2))
            await clock.sleep(0.05)

    tasks = [asyncio.ensure_future(c) for c in (emu.run(), base.run(), command())]
    try:
        await clock.run(until_s=5.0)
        assert emu.state == p.McuState.ARMED, (base.health(), emu.boots, emu.opens)
        assert emu.wheel_duties == (530, 530, 530, -530, -530, -530)
        got = wheels.drain()
        assert got[-1].stamp - got[0].stamp == pytest.approx(len(got) / 30.0, rel=0.1), (
            got[0].stamp, got[-1].stamp, len(got), base.health())
        h = base.health()
        assert h.state == "ok" and h.counters["link_losses"] == 0, h
        assert h.counters["tx_holds"] == 0 and h.counters["reconnects"] == 0, h
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        emu.close()


async def test_old_firmware_protocol_says_reflash() -> None:
    clock = RealClock()
    bus = make_bus()
    emu = ArduinoEmulator(FakeWorld(), clock, boot_delay_s=0.1)
    emu.firmware.proto_version = 0
    emu.open()
    base = ArduinoBase(FAST, RobotModel.from_config(RobotConfig()), bus, clock, port=emu.port_path)
    tasks = [asyncio.ensure_future(emu.run()), asyncio.ensure_future(base.run())]
    try:
        ok = await clock.wait_until(lambda: "speaks protocol 0" in base.last_error, 3.0,
                                    poll_s=0.01)
        assert ok, base.health()
        assert "firmware/README.md" in base.last_error
        assert emu.state != p.McuState.ARMED and not any(emu.wheel_duties)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        emu.close()


async def test_port_held_by_another_program() -> None:
    import serial

    clock = RealClock()
    emu = ArduinoEmulator(FakeWorld(), clock, boot_delay_s=0.1)
    emu.open()
    holder = serial.Serial(emu.port_path, 115200, exclusive=True)  # e.g. a serial monitor
    base = ArduinoBase(FAST, RobotModel.from_config(RobotConfig()), make_bus(), clock,
                       port=emu.port_path)
    task = asyncio.ensure_future(base.run())
    try:
        ok = await clock.wait_until(lambda: base.health().state == "error", 2.0, poll_s=0.01)
        assert ok
        assert "no other program" in base.health().message
        holder.close()  # the other program lets go: the driver takes over by itself
        emu_task = asyncio.ensure_future(emu.run())
        try:
            assert await clock.wait_until(lambda: base.mcu_state == p.McuState.ARMED, 4.0,
                                          poll_s=0.01), base.health()
        finally:
            emu_task.cancel()
            await asyncio.gather(emu_task, return_exceptions=True)
    finally:
        holder.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        emu.close()


async def test_rc_transmitter_teleop() -> None:
    from curio.core.topics import CMD_VEL_TELEOP

    cfg = FAST.model_copy(update={"rc_enabled": True})
    async with make_rig(cfg) as rig:
        teleop = rig.bus.subscribe(CMD_VEL_TELEOP, maxsize=100)
        sticks = [1500] * 12
        sticks[0], sticks[1], sticks[4] = 1900, 1300, 1000  # full ahead, half right, on
        rig.emu.firmware.rc_channels_us = tuple(sticks)
        await rig.clock.sleep(0.3)
        got = teleop.drain()
        assert len(got) >= 3  # 20 Hz
        assert got[-1].linear_mps == pytest.approx(0.37)
        assert got[-1].angular_radps == pytest.approx(-0.5 * 1.45)
        assert got[-1].source == "rc"
        sticks[4] = 1900  # the transmitter's switch turns teleop off
        rig.emu.firmware.rc_channels_us = tuple(sticks)
        await rig.clock.sleep(0.1)
        teleop.drain()
        await rig.clock.sleep(0.3)
        assert teleop.drain() == []
        sticks[4] = 1000
        rig.emu.firmware.rc_channels_us = tuple(sticks)
        rig.emu.firmware.rc_flags = p.RC_FAILSAFE  # receiver failsafe: nothing is published
        await rig.clock.sleep(0.1)
        teleop.drain()
        await rig.clock.sleep(0.3)
        assert teleop.drain() == []
        assert rig.base.rc is not None and rig.base.rc.flags & p.RC_FAILSAFE
