"""LX-16A packets: byte vectors from hardware.md §4.3, the parser, the dead-zone reading model."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curio.drivers.arduino import lx16a


@pytest.mark.parametrize(("packet", "expected"), [
    (lx16a.read_request(11, lx16a.Cmd.POS_READ), "55550B031CD5"),
    (lx16a.position_reply(11, 500), "55550B051CF401DE"),
    (lx16a.position_reply(11, -194), "55550B051C3EFF96"),
    (lx16a.motor_mode(11, 500), "55550B071D0100F401DA"),
    (lx16a.motor_mode(21, -530), "555515071D0100EEFDDA"),
    (lx16a.position_mode(111), "55556F071D000000006C"),
    (lx16a.move_time(111, 500, 50), "55556F0701F401320061"),
    (lx16a.angle_offset_adjust(111, -10), "55556F0411F685"),
    (lx16a.build(111, lx16a.Cmd.ANGLE_OFFSET_WRITE), "55556F03127B"),
    (lx16a.read_request(11, lx16a.Cmd.VIN_READ), "55550B031BD6"),
    (lx16a.vin_reply(11, 7400), "55550B051BE81CD0"),
    (lx16a.read_request(1, lx16a.Cmd.VIN_READ), "555501031BE0"),
    (lx16a.read_request(lx16a.BROADCAST_ID, lx16a.Cmd.ID_READ), "5555FE030EF0"),
])
def test_byte_vectors(packet: bytes, expected: str) -> None:
    assert packet == bytes.fromhex(expected)


def test_motor_duty_is_clamped() -> None:
    assert lx16a.motor_mode(11, 5000) == lx16a.motor_mode(11, 1000)


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="trim 200"):
        lx16a.angle_offset_adjust(111, 200)
    with pytest.raises(ValueError, match="servo id 300"):
        lx16a.build(300, 1)


def test_parser_tolerates_echo_and_noise() -> None:
    parser = lx16a.PacketParser()
    request = lx16a.read_request(11, lx16a.Cmd.POS_READ)
    bad = bytearray(lx16a.position_reply(11, 42))
    bad[-1] ^= 0xFF
    stream = request + b"\x13\x55" + bytes(bad) + lx16a.position_reply(11, -194)
    packets = parser.feed(stream[:7]) + parser.feed(stream[7:])
    assert [(pk.servo_id, pk.cmd, pk.params) for pk in packets] == [
        (11, lx16a.Cmd.POS_READ, b""),  # the echo of the request: no params
        (11, lx16a.Cmd.POS_READ, b"\x3e\xff"),
    ]
    assert packets[1].i16() == -194
    assert parser.bad_checksums == 2  # the stray 55 makes a false header, then the bad reply


@settings(max_examples=100, deadline=None)
@given(servo_id=st.integers(0, 254), cmd=st.integers(0, 255),
       params=st.binary(max_size=10), noise=st.binary(max_size=20))
def test_build_parse_round_trip(servo_id: int, cmd: int, params: bytes, noise: bytes) -> None:
    packet = lx16a.build(servo_id, cmd, params)
    got = lx16a.PacketParser().feed(noise.replace(b"\x55", b"") + packet)
    assert got[-1] == lx16a.Lx16aPacket(servo_id, cmd, params)


def test_dead_zone_reading_model() -> None:
    assert lx16a.reading_from_count(0) == 0
    assert lx16a.reading_from_count(1189) == 1189
    assert lx16a.reading_from_count(1306) == -194  # leaving the zone forward reads −194
    assert lx16a.reading_from_count(1499) == -1
    assert lx16a.reading_from_count(1500 + 42) == 42
    inside = [lx16a.reading_from_count(c) for c in range(1190, 1306)]
    assert all(1182 <= r <= 1194 for r in inside)  # sticky near the top, drifting back
