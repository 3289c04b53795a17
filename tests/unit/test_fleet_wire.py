"""The fleet's wire: key expressions, payload encodings and the in-process transport."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.core.messages import GridMessage, LaserScan
from curio.fleet import codec
from curio.fleet.keys import check_rover_name, keyexpr_intersects, rover_of
from curio.fleet.transport import MemoryNetwork, MemoryTransport, Sample


@pytest.mark.parametrize("a, b, hit", [
    ("curio/*/status", "curio/r1/status", True),
    ("curio/*/status", "curio/r1/pose", False),
    ("curio/*/status", "curio/@fleet/status", False),
    ("curio/**", "curio/r1/q/map", True),
    ("curio/r1/q/*", "curio/r1/q/map", True),
    ("curio/r1/q/*", "curio/r1/q", False),
    ("curio/*/alive", "curio/@fleet/manager", False),
    ("0/**", "0/r1/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_x", True),
])
def test_key_expressions_match_like_zenoh(a: str, b: str, hit: bool) -> None:
    assert keyexpr_intersects(a, b) is hit
    assert keyexpr_intersects(b, a) is hit


def test_rover_names_are_key_chunks() -> None:
    assert check_rover_name("r-1_A") == "r-1_A"
    for bad in ("", "a/b", "*", "@x", "a" * 33):
        with pytest.raises(ValueError, match="not allowed"):
            check_rover_name(bad)
    assert rover_of("curio/r2/status") == "r2"
    assert rover_of("curio/@fleet/manager") is None


def test_json_payloads_are_compact_and_refuse_non_objects() -> None:
    data = codec.dumps({"x": 1.23456, "bad": math.inf, "list": [0.1111, 2]})
    assert codec.loads(data) == {"x": 1.235, "bad": None, "list": [0.111, 2]}
    for bad in (b"[1]", b"\xff", b"{"):
        with pytest.raises(codec.DecodeError):
            codec.loads(bad)


def test_a_thinned_scan_keeps_the_nearest_return_of_each_sector() -> None:
    n = 360
    ranges = np.full(n, 5.0, dtype=np.float32)
    ranges[180] = 1.234  # straight ahead
    ranges[:10] = np.inf
    scan = LaserScan(0.0, -math.pi, 2 * math.pi / n, 0.15, 12.0, ranges)
    frame = codec.decode_scan(codec.encode_scan(scan, Pose2D(1.0, 2.0, 0.5), 10.0, 90))
    assert len(frame.ranges_m) == 90 and frame.wall_s == 10.0
    assert np.isinf(frame.ranges_m[0]) and frame.ranges_m[45] == pytest.approx(1.23, abs=0.01)
    pts = frame.points()
    near = pts[np.argmin(np.hypot(pts[:, 0] - 1.0, pts[:, 1] - 2.0))]
    assert near == pytest.approx([1.0 + 1.23 * math.cos(0.5), 2.0 + 1.23 * math.sin(0.5)],
                                 abs=0.03)


def test_a_map_survives_the_wire() -> None:
    data = np.zeros((30, 40), dtype=np.int8)
    data[5, 7] = 100
    data[0, :] = -1
    grid = GridMessage(0.0, data, 0.05, Pose2D(-1.0, -2.0, 0.0), version=3)
    back = codec.decode_map(codec.encode_map(grid))
    assert np.array_equal(back.data, data) and back.origin == grid.origin
    assert back.version == 3 and codec.grid_digest(back.data) == codec.grid_digest(data)


def test_thin_path_keeps_ends_and_spacing() -> None:
    pts = [(0.05 * i, 0.0) for i in range(101)]
    thin = codec.thin_path(pts, 0.5)
    assert thin[0] == (0.0, 0.0) and thin[-1] == pts[-1]
    assert all(b[0] - a[0] >= 0.5 - 1e-9 for a, b in itertools.pairwise(thin[:-1]))


def test_memory_transport_delivers_in_sender_order_and_obeys_a_cut() -> None:
    net = MemoryNetwork()
    a, b, m = (MemoryTransport(n, net) for n in ("a", "b", "m"))
    got: list[Sample] = []
    live: list[tuple[str, str]] = []
    m.subscribe("curio/*/pose", got.append)
    m.watch_liveliness("curio/*/alive", lambda s: live.append((s.key, s.kind)))
    for t in (a, b):
        t.declare_token(f"curio/{t.name}/alive")
    for t in (m, a, b):
        t.open()
    b.put("curio/b/pose", b"1")
    a.put("curio/a/pose", b"2")
    a.put("curio/a/pose", b"3")
    assert m.pump() == 5
    assert [(s.source, s.payload) for s in got] == [("a", b"2"), ("a", b"3"), ("b", b"1")]
    assert sorted(live) == [("curio/a/alive", "put"), ("curio/b/alive", "put")]
    a.cut()
    a.put("curio/a/pose", b"lost")
    m.pump()
    assert live[-1] == ("curio/a/alive", "delete") and len(got) == 3
    assert a.stats.dropped == 1 and not a.connected
    a.restore()
    m.pump()
    assert live[-1] == ("curio/a/alive", "put")


def test_memory_queries_reach_the_queryables() -> None:
    net = MemoryNetwork()
    a, m = MemoryTransport("a", net), MemoryTransport("m", net)
    a.queryable("curio/a/q/*", lambda key, params: [("curio/a/q/map", b"M")])
    a.open()
    m.open()
    assert [(s.key, s.payload) for s in m.get("curio/*/q/map")] == [("curio/a/q/map", b"M")]
    a.cut()
    assert m.get("curio/*/q/map") == []
