"""RPLidar protocol: byte vectors from hardware.md §5 and property-based round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curio.drivers.rplidar import protocol as p


def test_request_vectors() -> None:
    assert p.encode_request(p.Cmd.STOP) == bytes.fromhex("A525")
    assert p.encode_request(p.Cmd.RESET) == bytes.fromhex("A540")
    assert p.encode_request(p.Cmd.SCAN) == bytes.fromhex("A520")
    assert p.encode_request(p.Cmd.FORCE_SCAN) == bytes.fromhex("A521")
    assert p.encode_request(p.Cmd.GET_INFO) == bytes.fromhex("A550")
    assert p.encode_request(p.Cmd.GET_HEALTH) == bytes.fromhex("A552")
    # Motor PWM 660 and 0 (hardware.md §5.2).
    assert p.encode_request(p.Cmd.SET_MOTOR_PWM, (660).to_bytes(2, "little")) == bytes.fromhex(
        "A5F0029402C1"
    )
    assert p.encode_request(p.Cmd.SET_MOTOR_PWM, b"\0\0") == bytes.fromhex("A5F002000057")
    assert p.encode_request(p.Cmd.EXPRESS_SCAN, bytes(5)) == bytes.fromhex("A58205000000000022")


def test_request_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match="takes no payload"):
        p.encode_request(p.Cmd.SCAN, b"\x01")
    with pytest.raises(ValueError, match="byte"):
        p.encode_request(300)


def test_descriptor_vectors() -> None:
    assert bytes.fromhex("A55A0500004081") == p.SCAN_DESCRIPTOR
    assert bytes.fromhex("A55A1400000004") == p.INFO_DESCRIPTOR
    assert bytes.fromhex("A55A0300000006") == p.HEALTH_DESCRIPTOR
    d = p.parse_descriptor(bytes.fromhex("A55A5400004082"))
    assert (d.length, d.mode, d.data_type) == (84, 1, 0x82)
    with pytest.raises(ValueError, match="A5 5A"):
        p.parse_descriptor(bytes.fromhex("A55B0500004081"))


def test_health_is_little_endian() -> None:
    h = p.HealthStatus.decode(bytes.fromhex("020180"))
    assert (h.status, h.error_code, h.name) == (2, 0x8001, "error")
    assert h.encode() == bytes.fromhex("020180")


def test_info_roundtrip_and_names() -> None:
    info = p.DeviceInfo(0x18, 29, 1, 7, bytes(range(16)))
    assert p.DeviceInfo.decode(info.encode()) == info
    assert info.model_name == "A1M8"
    assert info.firmware == "1.29"


def test_node_vectors() -> None:
    node = p.decode_node(bytes.fromhex("3D412D4A13"))
    assert node is not None
    assert node.start and node.quality == 15
    assert node.angle_deg == pytest.approx(90.5)
    assert node.distance_mm == pytest.approx(1234.5)
    assert p.encode_node(True, 15, int(90.5 * 64), int(1234.5 * 4)) == bytes.fromhex("3D412D4A13")
    invalid = p.decode_node(bytes.fromhex("3E01000000"))
    assert invalid is not None and not invalid.start and invalid.distance_mm == 0
    # S == !S, or C == 0: misaligned.
    assert p.decode_node(bytes.fromhex("3F412D4A13")) is None
    assert p.decode_node(bytes.fromhex("3D402D4A13")) is None


node_st = st.tuples(
    st.booleans(),
    st.integers(0, 63),
    st.integers(0, 360 * 64 - 1),
    st.integers(0, 65535),
)


@given(node_st)
def test_node_roundtrip(values: tuple[bool, int, int, int]) -> None:
    start, quality, angle_q6, dist_q2 = values
    node = p.decode_node(p.encode_node(start, quality, angle_q6, dist_q2))
    assert node == p.Node(start, quality, angle_q6 / 64.0, dist_q2 / 4.0)


@given(st.lists(node_st, min_size=1, max_size=60), st.integers(1, 17))
@settings(max_examples=60)
def test_stream_decoder_any_split(nodes: list[tuple[bool, int, int, int]], chunk: int) -> None:
    data = b"".join(p.encode_node(*n) for n in nodes)
    dec = p.NodeStreamDecoder()
    batches = [dec.feed(data[i : i + chunk]) for i in range(0, len(data), chunk)]
    out = p.NodeBatch.concat(batches)
    assert len(out) == len(nodes)
    assert dec.resync_bytes == 0
    assert list(out.angle_deg) == [n[2] / 64.0 for n in nodes]
    assert list(out.distance_mm) == [n[3] / 4.0 for n in nodes]
    assert list(out.start) == [n[0] for n in nodes]


def _reference_decode(data: bytes) -> list[tuple[bool, float, float]]:
    """Byte-at-a-time decoding with the documented resync rule (drop one byte)."""
    out, i = [], 0
    while len(data) - i >= 5:
        node = p.decode_node(data[i : i + 5])
        if node is None or node.angle_deg >= 360.0:
            i += 1
            continue
        out.append((node.start, node.angle_deg, node.distance_mm))
        i += 5
    return out


@given(st.lists(node_st, max_size=30), st.binary(max_size=12), st.integers(0, 30),
       st.integers(1, 40))
@settings(max_examples=150)
def test_stream_decoder_equals_bytewise_resync(
    nodes: list[tuple[bool, int, int, int]], garbage: bytes, where: int, chunk: int
) -> None:
    encoded = [p.encode_node(*n) for n in nodes]
    data = b"".join(encoded[:where]) + garbage + b"".join(encoded[where:])
    dec = p.NodeStreamDecoder()
    out = p.NodeBatch.concat([dec.feed(data[i : i + chunk]) for i in range(0, len(data), chunk)])
    got = list(zip(out.start.tolist(), out.angle_deg.tolist(), out.distance_mm.tolist(),
                   strict=True))
    assert got == _reference_decode(data)


def test_stream_decoder_recovers_a_realistic_revolution_after_garbage() -> None:
    rng = np.random.default_rng(3)
    n = 360
    angle_q6 = np.round(np.arange(n) * 64.0 + rng.uniform(0, 30, n)).astype(np.int64)
    dist_q2 = rng.integers(600, 40000, n)
    quality = rng.integers(10, 48, n)
    start = np.zeros(n, bool)
    start[0] = True
    clean = p.encode_nodes(start, quality, angle_q6, dist_q2)
    dirty = bytearray(clean)
    for at in (1003, 702, 305):  # garbage in three places (inserted back to front)
        dirty[at:at] = rng.integers(0, 256, 9, dtype=np.uint8).tobytes()
    dec = p.NodeStreamDecoder()
    out = dec.feed(bytes(dirty))
    assert dec.resync_bytes > 0
    real = set(zip((angle_q6 / 64.0).tolist(), (dist_q2 / 4.0).tolist(), strict=True))
    got = list(zip(out.angle_deg.tolist(), out.distance_mm.tolist(), strict=True))
    recovered = [g for g in got if g in real]
    assert len(recovered) >= n - 6  # at most two real nodes lost around each garbage burst
    assert recovered == sorted(recovered)  # in order
    assert len(got) - len(recovered) <= 27 // 3  # false nodes come only from the garbage


def test_request_parser_handles_split_and_bad_checksum() -> None:
    parser = p.RequestParser()
    good = p.encode_request(p.Cmd.SET_MOTOR_PWM, b"\x94\x02")
    bad = good[:-1] + bytes((good[-1] ^ 0xFF,))
    stream = b"\x00\x13" + p.encode_request(p.Cmd.GET_INFO) + bad + good + b"\xa5"
    reqs = []
    for i in range(0, len(stream), 3):
        reqs += parser.feed(stream[i : i + 3])
    reqs += parser.feed(b"\x25")
    assert [r.cmd for r in reqs] == [p.Cmd.GET_INFO, p.Cmd.SET_MOTOR_PWM, p.Cmd.STOP]
    assert reqs[1].payload == b"\x94\x02"
    assert parser.bad_checksums == 1
    assert parser.skipped_bytes == 2


def test_assembler_cuts_revolutions_at_start_flag() -> None:
    def rev_bytes(n: int) -> bytes:
        return b"".join(
            p.encode_node(i == 0, 20, int(i * 360 / n * 64), 4000) for i in range(n)
        )

    data = rev_bytes(50)[5 * 30 :] + rev_bytes(50) + rev_bytes(40) + rev_bytes(10)
    dec, asm = p.NodeStreamDecoder(), p.ScanAssembler(min_nodes=20)
    revs = asm.feed(dec.feed(data))
    # The partial revolution before the first S is dropped; the last one is still open.
    assert [len(r) for r in revs] == [50, 40]
    # A start flag only 10 nodes into a revolution is a false one: it does not cut.
    assert asm.feed(dec.feed(p.encode_node(True, 1, 0, 0))) == []
    # Nor does a start flag far from the raw 0° (garbage that passed the check bits).
    assert asm.feed(dec.feed(p.encode_node(True, 1, 180 * 64, 0) * 30)) == []
    # The revolution those nodes made (10 nodes 36° apart, 31 at 0° and 180°) leaves wide
    # gaps round the circle: not a whole scan, dropped (what it lacks would read as free).
    assert asm.feed(dec.feed(rev_bytes(20))) == [] and asm.partial_scans == 1
    # 20 nodes 18° apart: dropped too; the A1's 360 nodes a revolution are a scan
    assert [len(r) for r in asm.feed(dec.feed(rev_bytes(360) + rev_bytes(10)))] == [360]
    assert asm.partial_scans == 2 and asm.revolutions == 3


def test_angle_conversion_matches_rplidar_ros() -> None:
    # raw 0° (the lidar's own front) is laser-frame pi; raw 90° (clockwise) is +90° in laser.
    raw = np.array([0.0, 90.0, 180.0, 270.0])
    laser = p.raw_to_laser_rad(raw)
    assert laser == pytest.approx([-math.pi, math.pi / 2, 0.0, -math.pi / 2])
    assert p.laser_to_raw_deg(laser) % 360 == pytest.approx(raw)


def test_revolution_binning_nearest_and_invalid() -> None:
    raw = np.array([180.0, 180.2, 90.0, 0.0])  # laser 0, ~-0.2°, +90°, pi
    rev = p.NodeBatch(
        np.array([True, False, False, False]),
        np.array([10, 30, 20, 0], dtype=np.uint8),
        raw,
        np.array([2000.0, 1500.0, 100.0, 0.0]),  # 0.1 m is below range_min, 0 is invalid
    )
    ranges, intens = p.revolution_to_ranges(rev, 360, 0.15, 12.0)
    assert ranges[180] == pytest.approx(1.5)  # nearest of the two samples in bin 0 rad
    assert intens[180] == 30
    assert math.isinf(ranges[270]) and math.isinf(ranges[0])
    assert int(np.isfinite(ranges).sum()) == 1
