"""The Pi ↔ Mega frame protocol: byte vectors from hardware.md §3.2 and property round-trips."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curio.drivers.arduino import protocol as p


def test_crc_check_value() -> None:
    assert p.crc16(b"123456789") == 0x29B1


def test_heartbeat_vector() -> None:
    frame = p.encode(p.Heartbeat(host_ms=1000), seq=1)
    assert frame == bytes.fromhex("CAFE040105E803000086 0E".replace(" ", ""))


def test_estop_vector() -> None:
    assert p.encode(p.Estop(), seq=3) == bytes.fromhex("CAFE000303ACA9")


def test_servo_cmd_vector() -> None:
    frame = p.encode(p.ServoCmd((530, 530, 530, -530, -530, -530), (500,) * 4, 1), seq=2)
    # hardware.md prints this frame with a stray 29th byte (0x21) after the CRC; the frame is
    # LEN + 7 = 28 bytes and its CRC is C1 02.
    assert frame == bytes.fromhex(
        "CAFE150202" "120212021202" "EEFDEEFDEEFD" "F401F401F401F401" "01" "C102")
    assert len(frame) == 21 + 7


def test_payload_sizes_match_the_spec() -> None:
    assert len(p.SetConfig().pack()) == 22
    assert len(p.ServoCmd((0,) * 6, (500,) * 4).pack()) == 21
    assert len(p.ServoPos(0, 0x3FF, (0,) * 6, (0,) * 4).pack()) == 36
    status = p.ServoStatus(0, tuple(p.ServoStatusEntry(i, 7400) for i in range(10)))
    assert len(status.pack()) == 74
    assert len(p.State(0, 1).pack()) == 18
    assert len(p.Info(1, 1, 0).pack()) == 9


def test_servo_pos_example_header() -> None:
    frame = p.encode(p.ServoPos(0, 0x3FF, (0,) * 6, (0,) * 4), seq=7)
    assert frame[:5] == bytes.fromhex("CAFE240781")


def test_decoder_split_and_two_frames_in_one_read() -> None:
    a = p.encode(p.Arm(True), 1)
    b = p.encode(p.Heartbeat(5), 2)
    dec = p.FrameDecoder()
    stream = a + b
    got = []
    for i in range(0, len(stream), 3):  # split across reads
        got += dec.feed(stream[i:i + 3])
    assert [(f.seq, f.msg_id) for f in got] == [(1, p.MsgId.ARM), (2, p.MsgId.HEARTBEAT)]
    dec2 = p.FrameDecoder()
    assert len(dec2.feed(a + b)) == 2  # two frames in one read


def test_decoder_resyncs_at_byte_after_failing_sync() -> None:
    good = p.encode(p.Estop(), 9)
    bad = bytearray(p.encode(p.Arm(True), 1))
    bad[5] ^= 0x01
    dec = p.FrameDecoder()
    # garbage, a false sync, a corrupt frame whose payload hides a real frame start, a frame
    frames = dec.feed(b"\x00\x13\xca" + bytes(bad) + good)
    assert [f.seq for f in frames] == [9]
    assert dec.stats.crc_errors == 1
    assert dec.stats.resyncs >= 1
    assert dec.stats.garbage_bytes >= 3


def test_decoder_truncated_frame_then_good_frame() -> None:
    good = p.encode(p.State(1, 2), 4)
    dec = p.FrameDecoder()
    frames = dec.feed(good[:10] + good + good)
    # The truncated frame swallows bytes of the next one and fails its CRC; the hunt restarts
    # one byte after its sync, so at worst one frame is lost.
    assert len(frames) >= 1
    assert all(f.payload == p.State(1, 2).pack() for f in frames)
    assert dec.stats.crc_errors >= 1


def test_decoder_rejects_long_length() -> None:
    dec = p.FrameDecoder()
    assert dec.feed(b"\xca\xfe\xc9\x00\x00" + p.encode(p.Estop(), 1)) != []
    assert dec.stats.length_errors == 1


def test_bad_payloads_raise_protocol_error() -> None:
    with pytest.raises(p.ProtocolError, match="SERVO_CMD payload must be 21 bytes"):
        p.decode_message(p.Frame(0, p.MsgId.SERVO_CMD, b"\x00" * 5))
    with pytest.raises(p.ProtocolError, match="unknown message id 0x3F"):
        p.decode_message(p.Frame(0, 0x3F, b""))
    with pytest.raises(p.ProtocolError, match="at most 200"):
        p.encode_frame(1, 0, b"\x00" * 201)
    with pytest.raises(p.ProtocolError, match="out of range"):
        p.ServoCmd((40000,) * 6, (0,) * 4).pack()


def test_set_config_problems_name_the_field() -> None:
    assert p.SetConfig().problems() == []
    assert "servo ids" in p.SetConfig(wheel_ids=(1, 1, 2, 3, 4, 5)).problems()[0]
    assert "cmd_timeout_ms" in p.SetConfig(cmd_timeout_ms=10).problems()[0]


# --- properties -----------------------------------------------------------------------------

i16 = st.integers(-32768, 32767)
u16 = st.integers(0, 0xFFFF)
u8 = st.integers(0, 0xFF)
u32 = st.integers(0, 0xFFFFFFFF)

messages = st.one_of(
    st.builds(p.SetConfig, wheel_ids=st.tuples(*[u8] * 6), steer_ids=st.tuples(*[u8] * 4),
              steer_trim=st.tuples(*[st.integers(-128, 127)] * 4), cmd_timeout_ms=u16,
              pos_rate_hz=u8, status_rate_hz=u8, steer_move_ms=u16, flags=u8, proto_ver=u8),
    st.builds(p.ServoCmd, wheel_duty=st.tuples(*[i16] * 6), steer_pos=st.tuples(*[u16] * 4),
              flags=u8),
    st.builds(p.Estop),
    st.builds(p.Arm, arm=st.booleans()),
    st.builds(p.Heartbeat, host_ms=u32),
    st.builds(p.GetInfo),
    st.builds(p.ServoRaw, data=st.binary(max_size=30)),
    st.builds(p.Ack, acked_seq=u8, acked_id=u8, status=u8),
    st.builds(p.ServoPos, t_ms=u32, valid_mask=u16, wheel_pos=st.tuples(*[i16] * 6),
              steer_pos=st.tuples(*[i16] * 4), dt_ms=st.tuples(*[u8] * 10)),
    st.builds(p.ServoStatus, t_ms=u32, servos=st.tuples(*[st.builds(
        p.ServoStatusEntry, servo_id=u8, vin_mv=u16, temp_c=u8, mode=u8, led_error=u8,
        comm_errs=u8)] * 10)),
    st.builds(p.RcChannels, t_ms=u32, flags=u8, frame_counter=u8,
              channels_us=st.lists(u16, max_size=16).map(tuple)),
    st.builds(p.State, t_ms=u32, state=u8, faults=u16, last_host_ms=u32, rx_crc_err=u16,
              rx_ok=u16, loop_max_us=u16, reset_cause=u8),
    st.builds(p.Battery, servo_vin_mv=u16, adc_mv=u16),
    st.builds(p.Info, proto_ver=u8, fw_major=u8, fw_minor=u8, build=u32, config_crc=u16),
    st.builds(p.ServoRawReply, status=u8, data=st.binary(max_size=30)),
    st.builds(p.Log, level=u8, text=st.text(alphabet=st.characters(min_codepoint=32,
                                                                   max_codepoint=126),
                                            max_size=60)),
)


@settings(max_examples=300, deadline=None)
@given(msg=messages, seq=u8)
def test_encode_decode_identity(msg: p.Message, seq: int) -> None:
    frames = p.FrameDecoder().feed(p.encode(msg, seq))
    assert len(frames) == 1
    assert frames[0].seq == seq
    assert p.decode_message(frames[0]) == msg


@settings(max_examples=80, deadline=None)
@given(garbage=st.binary(max_size=300), msgs=st.lists(messages, min_size=1, max_size=5),
       cut=st.integers(3, 64))
def test_garbage_prefixed_stream_resyncs(garbage: bytes, msgs: list[p.Message],
                                         cut: int) -> None:
    stream = b"".join(p.encode(m, i) for i, m in enumerate(msgs))
    # Garbage may itself contain a sync and a huge length that swallows what follows; a lone
    # frame with LEN 200 of zeros flushes it (as the next real traffic does on the link).
    flush = p.encode_frame(p.MsgId.LOG, 0xAA, b"\x00" * 200)
    data = garbage + flush + stream
    dec = p.FrameDecoder()
    got: list[p.Frame] = []
    for i in range(0, len(data), cut):
        got += dec.feed(data[i:i + cut])
    decoded = [p.decode_message(f) for f in got if f.seq != 0xAA or f.msg_id != p.MsgId.LOG]
    assert decoded[-len(msgs):] == msgs


@settings(max_examples=150, deadline=None)
@given(msg=messages, seq=u8, data=st.data())
def test_single_bit_corruption_is_detected(msg: p.Message, seq: int,
                                           data: st.DataObject) -> None:
    frame = bytearray(p.encode(msg, seq))
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    dec = p.FrameDecoder()
    frames = dec.feed(bytes(frame))
    assert frames == []
