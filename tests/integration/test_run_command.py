"""``curio run``: the whole app on the real clock; Ctrl-C and SIGTERM stop the rover first."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import REPO_ROOT, Config
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL, CMD_VEL_TELEOP, SERVO_CMD


async def test_stop_sends_zero_velocity_and_stops_the_wheels(cfg: Config) -> None:
    clock = SimClock(speed=None)
    app = App(cfg, clock, web=False)
    cmd_sub = app.bus.subscribe(CMD_VEL, maxsize=1000)
    servo_sub = app.bus.subscribe(SERVO_CMD, maxsize=1000)
    await app.start()
    runner = asyncio.create_task(clock.run())

    async def drive() -> None:
        async for t in clock.every(0.05):
            app.bus.publish(CMD_VEL_TELEOP, Twist(t, 0.2, 0.0, source="test"))
            if t > 3.0:
                return

    await drive()
    moving = [c for c in cmd_sub.drain() if c.linear_mps > 0.1]
    assert moving, "teleop should have reached /cmd_vel through the safety stage"
    assert any(any(d != 0 for d in s.wheel_duty) for s in servo_sub.drain())
    await app.stop()
    runner.cancel()
    last_cmd = cmd_sub.drain()[-1]
    assert (last_cmd.linear_mps, last_cmd.angular_radps) == (0.0, 0.0)
    last_servo = servo_sub.drain()[-1]
    assert all(d == 0 for d in last_servo.wheel_duty)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_stops_the_rover_then_exits_cleanly(tmp_path: Path, sig: int) -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "curio", "run", "--config", str(REPO_ROOT / "config.toml"),
         "--set", f'data_dir="{tmp_path}"', "--set", "web.port=0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp_path,
    )
    assert proc.stdout is not None
    lines: list[str] = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("dashboard: http://127.0.0.1:"):
            break
    else:
        pytest.fail("curio run never printed its dashboard URL:\n" + "".join(lines))
    assert "?token=" in lines[-1]
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=30)
    log = "".join(lines) + out
    assert proc.returncode == 0, log
    assert "stopping the rover" in log
    assert "Traceback" not in log
    assert (tmp_path / "web_tokens.json").is_file()  # the admin token made on the first start


async def test_a_crashed_part_is_reported_and_stops_the_stepper(cfg: Config) -> None:
    """failed_parts() is cheap while nothing crashed, and names a part whose run raised."""
    from curio.core.parts import Part

    clock = SimClock(speed=None)
    app = App(cfg, clock, web=False)

    async def boom() -> None:
        await clock.sleep(1.0)
        raise RuntimeError("broken part")

    app.add(Part("boom", run=boom))
    await app.start()
    assert app.failed_parts() == []
    await clock.run(until_s=30.0, stop=lambda: bool(app.failed_parts()))
    failed = app.failed_parts()
    assert [name for name, _ in failed] == ["boom"]
    assert isinstance(failed[0][1], RuntimeError)
    assert clock.now() == pytest.approx(1.0, abs=0.05)  # stopped right after the crash
    await app.stop()
