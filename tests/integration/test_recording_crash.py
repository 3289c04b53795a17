"""``curio run`` records by default, and ``kill -9`` loses at most about the last second."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from curio.core.clock import wall_sleep, wall_time
from curio.core.config import REPO_ROOT
from curio.record.library import list_recordings
from curio.record.reader import open_recording

pytestmark = pytest.mark.slow


def newest_time(path: Path) -> float:
    """The newest log time (UNIX s) in a recording, read as a crash would leave it."""
    return max((m.log_ns / 1e9 for m in open_recording(path).messages()), default=-math.inf)


def test_kill_9_loses_at_most_about_a_second(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "curio", "run", "--config", str(REPO_ROOT / "config.toml"),
         "--set", f'data_dir="{tmp_path}"', "--set", "web.enabled=false"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp_path)
    lags: list[float] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("Ctrl-C stops the rover"):
                break
        wall_sleep(1.5)
        (live,) = (tmp_path / "recordings").glob("curio-*.mcap")
        for k in range(12):  # what a crash at these instants would leave on disk
            wall_sleep(0.23 + 0.01 * k)
            copy = tmp_path / f"crash{k}.bin"
            at = wall_time()
            copy.write_bytes(live.read_bytes())
            lags.append(at - newest_time(copy))
        killed_at = wall_time()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    lags.append(killed_at - newest_time(live))
    assert max(lags) < 1.3, f"a crash would lose up to {max(lags):.2f} s: {lags}"
    rec = open_recording(live)
    times = [m.log_ns / 1e9 for m in rec.messages()]
    assert {"/scan", "/odom", "/pose", "/tf", "/health"} <= {m.channel for m in rec.messages()}
    assert times[-1] - times[0] > 3.0
    info = list_recordings(tmp_path / "recordings")[0]
    assert info.name == live.name and not info.complete and info.messages == len(times)
