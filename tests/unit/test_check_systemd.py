"""The systemd notifier used by deploy/curio.service (Type=notify, WatchdogSec)."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

from curio.core.clock import SimClock
from curio.core.messages import DriverHealth
from curio.core.topics import HEALTH, make_bus
from curio.drivers.health import SystemdNotifier


async def test_ready_watchdog_and_status(tmp_path: Path) -> None:
    path = str(tmp_path / "notify")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    server.setblocking(False)
    clock, bus = SimClock(), make_bus()
    notifier = SystemdNotifier(clock, bus, {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "4000000"})
    assert notifier.enabled and notifier.period_s == 2.0
    task = asyncio.create_task(notifier.run())
    await clock.advance(0.5)
    bus.publish(HEALTH, DriverHealth(0.5, "lidar", "error", "unplugged"))
    bus.publish(HEALTH, DriverHealth(0.6, "imu", "ok"))
    await clock.advance(4.0)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    got = []
    while True:
        try:
            got.append(server.recv(1024).decode())
        except BlockingIOError:
            break
    server.close()
    assert got[0].startswith("READY=1")
    pings = [g for g in got if g.startswith("WATCHDOG=1")]
    assert len(pings) == 3  # t = 0, 2, 4
    assert "STATUS=imu ok, lidar error" in pings[-1]
    assert got[-1] == "STOPPING=1"


async def test_disabled_without_systemd() -> None:
    notifier = SystemdNotifier(SimClock(), make_bus(), {})
    assert not notifier.enabled
    await notifier.run()  # returns at once
    assert notifier.sent == []
