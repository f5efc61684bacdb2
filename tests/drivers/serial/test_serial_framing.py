"""§2 framing: hand-computed byte vectors, round trips, and resynchronisation after corruption."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.serial.framing import (
    HEADER_SIZE,
    MAX_PAYLOAD,
    MAX_WIRE_FRAME,
    Frame,
    FrameDecoder,
    MsgType,
    encode_frame,
    frame_bytes,
    pack_header,
    unpack_header,
    wire_size,
)


def crc32_bitwise(data: bytes) -> int:
    """IEEE 802.3 CRC-32, reflected polynomial 0xEDB88320, one bit at a time (reference)."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def test_crc_reference_matches_the_standard_check_value() -> None:
    assert crc32_bitwise(b"123456789") == 0xCBF43926


def test_header_layout_is_little_endian_14_bytes() -> None:
    h = pack_header(MsgType.PING, 0x0201, 0x0102030405060708, 15)
    assert h == bytes([0x01, 0x01, 0x01, 0x02, 8, 7, 6, 5, 4, 3, 2, 1, 0x0F, 0x00])
    assert unpack_header(h) == (1, 1, 0x0201, 0x0102030405060708, 15)


def test_heartbeat_frame_matches_hand_computed_bytes() -> None:
    # HEARTBEAT header, seq 1, stamp 0, empty payload: 01 05 01 00 then ten zero bytes
    body = bytes([0x01, 0x05, 0x01, 0x00]) + bytes(10)
    assert pack_header(MsgType.HEARTBEAT, 1, 0, 0) == body
    crc = crc32_bitwise(body)
    assert crc == 0xCA3E67CD
    # COBS by hand: [01 05 01] ends at the first zero -> code 04; each of the next ten zeros is
    # an empty block -> code 01; the CRC bytes CD 67 3E CA (little-endian) close with code 05.
    expected = bytes([0x04, 0x01, 0x05, 0x01]) + bytes([0x01] * 10) + bytes(
        [0x05, 0xCD, 0x67, 0x3E, 0xCA, 0x00])
    assert encode_frame(body) == expected
    assert FrameDecoder().feed(expected) == [Frame(MsgType.HEARTBEAT, 1, 0, b"")]


def test_ping_frame_crc_covers_header_and_payload() -> None:
    payload = struct.pack("<HfffB", 7, 0.0, 0.0, 0.5, 1)
    wire = frame_bytes(MsgType.PING, 3, 42, payload)
    from cobs import cobs

    raw = cobs.decode(wire[:-1])
    body = raw[:-4]
    assert body[:HEADER_SIZE] == pack_header(MsgType.PING, 3, 42, len(payload))
    assert body[HEADER_SIZE:] == payload
    assert int.from_bytes(raw[-4:], "little") == crc32_bitwise(body)
    assert wire.count(0) == 1 and wire[-1] == 0


@pytest.mark.parametrize(("field", "args"), [
    ("msg_type", (0x42, 0, 0, 0)),
    ("seq", (MsgType.PING, 0x10000, 0, 0)),
    ("stamp_ns", (MsgType.PING, 0, -1, 0)),
    ("payload_len", (MsgType.PING, 0, 0, MAX_PAYLOAD + 1)),
], ids=["type", "seq", "stamp", "len"])
def test_header_rejects_out_of_range_fields(field: str, args: tuple[int, int, int, int]) -> None:
    with pytest.raises(ValueError, match=field):
        pack_header(*args)


frames_st = st.builds(
    Frame,
    st.sampled_from(list(MsgType)),
    st.integers(0, 0xFFFF),
    st.integers(0, 2**64 - 1),
    st.binary(max_size=MAX_PAYLOAD),
)


@settings(max_examples=60, deadline=None)
@given(st.lists(frames_st, min_size=1, max_size=5), st.integers(1, 512))
def test_round_trip_in_any_split(frames: list[Frame], split: int) -> None:
    wire = b"".join(encode_frame(f.body()) for f in frames)
    assert all(len(encode_frame(f.body())) <= wire_size(len(f.payload)) for f in frames)
    dec = FrameDecoder()
    out: list[Frame] = []
    for i in range(0, len(wire), split):
        out += dec.feed(wire[i:i + split])
    assert out == frames
    assert dec.dropped == 0


small_frames = st.builds(
    Frame, st.sampled_from(list(MsgType)), st.integers(0, 0xFFFF), st.integers(0, 2**64 - 1),
    st.binary(max_size=300),
)


@settings(max_examples=150, deadline=None)
@given(st.lists(small_frames, min_size=3, max_size=8), st.data())
def test_corruption_loses_only_the_hit_frame(frames: list[Frame], data: st.DataObject) -> None:
    """Corrupt one frame (bit flip, truncation, garbage, deletion): every other frame survives."""
    frames = [Frame(f.msg_type, i, f.stamp_ns, f.payload) for i, f in enumerate(frames)]
    wires = [encode_frame(f.body()) for f in frames]
    k = data.draw(st.integers(0, len(frames) - 1), label="victim")
    w = bytearray(wires[k])
    kind = data.draw(st.sampled_from(["flip", "truncate", "garbage", "delete"]), label="kind")
    if kind == "flip":
        pos = data.draw(st.integers(0, len(w) - 2))
        w[pos] ^= 1 << data.draw(st.integers(0, 7))
    elif kind == "truncate":
        w = w[:data.draw(st.integers(1, len(w) - 2))] + b"\x00"
    elif kind == "garbage":
        w[:0] = data.draw(st.binary(min_size=1, max_size=64).filter(lambda g: g[-1] != 0))
    else:
        del w[data.draw(st.integers(0, len(w) - 2))]
    wires[k] = bytes(w)
    dec = FrameDecoder()
    out = dec.feed(b"".join(wires))
    survivors = [f for i, f in enumerate(frames) if i != k]
    assert out == survivors
    assert dec.dropped >= 1
    # and the stream after the damage is in sync: one more frame decodes at once
    tail = Frame(MsgType.HEARTBEAT, 99, 0, b"")
    assert dec.feed(encode_frame(tail.body())) == [tail]


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=4000), st.integers(1, 97))
def test_decoder_never_raises_on_random_bytes(noise: bytes, split: int) -> None:
    dec = FrameDecoder()
    for i in range(0, len(noise), split):
        dec.feed(noise[i:i + split])
    good = Frame(MsgType.STATUS, 9, 9, b"ok")
    # one delimiter resynchronises: the frame after it decodes
    assert dec.feed(b"\x00" + encode_frame(good.body())) == [good]


def test_every_drop_reason_is_counted() -> None:
    dec = FrameDecoder()
    good = encode_frame(pack_header(MsgType.HEARTBEAT, 0, 0, 0))
    bad_crc = bytearray(good)
    bad_crc[2] ^= 0x40
    from cobs import cobs

    def wire(body: bytes) -> bytes:
        import zlib

        return cobs.encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"

    bad_version = wire(b"\x02" + pack_header(MsgType.HEARTBEAT, 0, 0, 0)[1:])
    bad_len = wire(pack_header(MsgType.HEARTBEAT, 0, 0, 3) + b"ab")
    bad_type = wire(b"\x01\x42" + pack_header(MsgType.HEARTBEAT, 0, 0, 0)[2:])
    short = wire(b"\x01\x05")
    bad_cobs = b"\x05\x01\x02\x00"  # code 05 promises 4 bytes, only 2 follow
    oversize = b"\x07" * (MAX_WIRE_FRAME + 10) + b"\x00"
    out = dec.feed(bytes(bad_crc) + bad_version + bad_len + bad_type + short + bad_cobs
                   + oversize + good)
    assert out == [Frame(MsgType.HEARTBEAT, 0, 0, b"")]
    assert dec.stats() == {
        "frames_ok": 1, "bytes_in": dec.bytes_in, "oversize": 1, "cobs_errors": 1,
        "length_errors": 2, "crc_errors": 1, "version_errors": 1, "type_errors": 1,
        "dropped": 7,
    }


def test_empty_frames_are_idle_bytes() -> None:
    dec = FrameDecoder()
    assert dec.feed(b"\x00\x00\x00") == []
    assert dec.dropped == 0
