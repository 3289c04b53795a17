"""Dashboard building blocks: rate limiter, frame encoding, wiring into the App."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan
from curio.core.messages import Path as PathMsg
from curio.web.auth import RateLimiter
from curio.web.encode import FRAME_LOCAL_PLAN, decode_frame, encode_path, encode_scan
from curio.web.inputs import describe_path_ids


def test_rate_limiter_bucket() -> None:
    limiter = RateLimiter(4.0)
    assert [limiter.allow(0.0) for _ in range(6)] == [True] * 4 + [False] * 2
    assert limiter.allow(0.25) is True  # one token back after 1/4 s
    assert limiter.allow(0.25) is False
    assert limiter.rejected == 3
    with pytest.raises(ValueError):
        RateLimiter(0.0)


def test_scan_frame_is_uint16_millimetres() -> None:
    ranges = np.array([0.1, 0.5, np.inf, np.nan, 12.5, 70.0], dtype=np.float32)
    scan = LaserScan(3.5, -math.pi, 0.01, 0.15, 12.0, ranges)
    data = encode_scan(scan, Pose2D(1.0, -2.0, 0.5))
    assert len(data) == 16 + 24 + 2 * 6
    frame = decode_frame(data)
    # below range_min, above range_max, inf, nan: all 0 = no valid return
    assert frame["ranges_mm"] == [0, 500, 0, 0, 0, 0]
    assert frame["stamp"] == 3.5
    assert frame["laser"] == pytest.approx((1.0, -2.0, 0.5))
    assert frame["angle_min"] == pytest.approx(-math.pi)


def test_path_frame_and_unknown_frames() -> None:
    msg = PathMsg(1.0, tuple(Pose2D(i * 0.5, -i * 0.25) for i in range(4)))
    frame = decode_frame(encode_path(msg, FRAME_LOCAL_PLAN))
    assert frame["type"] == FRAME_LOCAL_PLAN
    assert frame["points"] == [[0.0, 0.0], [0.5, -0.25], [1.0, -0.5], [1.5, -0.75]]
    assert decode_frame(encode_path(PathMsg(0.0, ())))["points"] == []
    with pytest.raises(ValueError, match="unknown frame type 99"):
        decode_frame(bytes([99]) + bytes(15))


def test_describe_path_ids() -> None:
    assert describe_path_ids([0, 1, 2, 3, 4]) == "0–4"
    assert describe_path_ids([0, 2, 5]) == "0, 2, 5"
    assert describe_path_ids([0, 1]) == "0, 1"
    assert describe_path_ids([]) == "none (create one first)"


async def test_build_web_sets_the_control_url(cfg: Config) -> None:
    cfg.web.port = 0
    app = App(cfg, SimClock(), web=True)
    try:
        assert app.web is not None and app.web.port > 0
        data = json.loads((Path(cfg.resolve(cfg.data_dir)) / cfg.web.tokens_file).read_text())
        (admin,) = data["tokens"]
        assert admin["name"] == "admin" and admin["role"] == "admin"
        assert app.web_url == f"http://127.0.0.1:{app.web.port}/?token={admin['token']}"
        assert any(p.name == "web" for p in app.parts)
    finally:
        await app.web.close()


def test_port_in_use_is_a_clear_error(cfg: Config) -> None:
    import socket

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    cfg.web.port = busy.getsockname()[1]
    try:
        with pytest.raises(OSError, match=r"set web\.port to a free port"):
            App(cfg, SimClock(), web=True)
    finally:
        busy.close()
