"""Payload layouts, echo encodings (int16 never clips), chunking and reassembly, link budget."""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from drivers.serial.framing import MAX_PAYLOAD, FrameDecoder, MsgType, frame_bytes
from drivers.serial.host import link_budget
from drivers.serial.protocol import (
    ECHO_HEADER,
    ConfigPayload,
    EchoAssembler,
    EchoChunk,
    Encoding,
    ErrorPayload,
    HeartbeatPayload,
    PingPayload,
    StatusPayload,
    chunk_echo,
    decode_samples,
    echo_wire_bytes,
    encode_samples,
    int16_scale,
)


def test_ping_payload_byte_layout() -> None:
    p = PingPayload(0x0102, 0.25, -0.5, 1.0, Encoding.IQ16)
    raw = p.pack()
    assert raw == bytes([0x02, 0x01]) + struct.pack("<f", 0.25) + struct.pack("<f", -0.5) + \
        struct.pack("<f", 1.0) + bytes([1])
    assert len(raw) == 15
    assert PingPayload.unpack(raw) == p


def test_echo_header_byte_layout() -> None:
    c = EchoChunk(5, 1, 3, Encoding.INT16, 2, 400000, 0.5, 24000, b"\x01\x00\x02\x00")
    raw = c.pack()
    assert ECHO_HEADER.size == 20
    assert raw[:20] == (bytes([5, 0, 1, 0, 3, 0, 0, 2]) + (400000).to_bytes(4, "little")
                        + struct.pack("<f", 0.5) + (24000).to_bytes(4, "little"))
    assert EchoChunk.unpack(raw) == c


@pytest.mark.parametrize("payload", [
    ConfigPayload(Encoding.IQ16, 1, 20000, 921600, 70000, 20),
    StatusPayload(2, Encoding.FLOAT32, 20, 70000, 1, 2, 3, 4, 5),
    HeartbeatPayload(123456, 1),
    ErrorPayload(3, 77, "over budget: 120 %"),
], ids=["config", "status", "heartbeat", "error"])
def test_designed_payloads_round_trip(payload: object) -> None:
    raw = payload.pack()  # type: ignore[attr-defined]
    assert type(payload).unpack(raw) == payload  # type: ignore[attr-defined]


@pytest.mark.parametrize("cls", [PingPayload, ConfigPayload, StatusPayload, HeartbeatPayload])
def test_wrong_length_payload_is_rejected(cls: Any) -> None:
    with pytest.raises(ValueError, match="payload"):
        cls.unpack(b"\x00" * 3)


def test_encoding_names() -> None:
    assert Encoding.parse("iq16") is Encoding.IQ16
    assert Encoding.parse("1") is Encoding.IQ16
    with pytest.raises(ValueError, match="encoding"):
        Encoding.parse("mp3")
    with pytest.raises(ValueError, match="encoding"):
        Encoding.parse(7)


finite = st.floats(-1e30, 1e30, allow_nan=False, allow_subnormal=True, width=64)


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 3), st.integers(1, 200)), elements=finite))
def test_int16_scale_never_clips(x: np.ndarray) -> None:
    enc = encode_samples(x, 400000, Encoding.INT16)
    q = np.frombuffer(enc.data, "<i2")
    assert np.all(np.abs(q) <= 32767)
    y = decode_samples(enc.data, Encoding.INT16, x.shape[0], enc.scale)
    # error bounded by half a step everywhere (no clipping at the peaks)
    assert np.all(np.abs(y - x) <= 0.5 * enc.scale * (1 + 1e-6) + 1e-300)
    peak = np.max(np.abs(x))
    if peak > 0:
        assert peak / enc.scale <= 32767.0
    if peak >= 32767 * float(np.finfo(np.float32).tiny):
        assert np.max(np.abs(q)) >= 32766  # the scale is tight: the peak uses the full range


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 2), st.integers(1, 100), st.just(2)),
                  elements=finite))
def test_iq16_scale_never_clips_either_component(parts: np.ndarray) -> None:
    z = parts[..., 0] + 1j * parts[..., 1]
    enc = encode_samples(z, 20000, Encoding.IQ16)
    y = decode_samples(enc.data, Encoding.IQ16, z.shape[0], enc.scale)
    half = 0.5 * enc.scale * (1 + 1e-6) + 1e-300
    assert np.all(np.abs(y.real - z.real) <= half)
    assert np.all(np.abs(y.imag - z.imag) <= half)


def test_int16_scale_edge_cases() -> None:
    assert int16_scale(0.0) == 1.0
    assert int16_scale(1e-44) > 0
    with pytest.raises(ValueError, match="finite"):
        int16_scale(math.inf)
    with pytest.raises(ValueError, match="NaN"):
        encode_samples(np.array([1.0, np.nan]), 400000, Encoding.INT16)
    with pytest.raises(ValueError, match="whole number"):
        encode_samples(np.zeros(4), 400000.5, Encoding.INT16)


def test_multichannel_samples_interleave_per_sample() -> None:
    x = np.array([[1.0, 2.0, 3.0], [10.0, 20.0, 30.0]])
    enc = encode_samples(x, 1000, Encoding.FLOAT32)
    assert np.frombuffer(enc.data, "<f4").tolist() == [1, 10, 2, 20, 3, 30]
    z = np.array([[1 + 2j, 3 + 4j]])
    enc = encode_samples(z, 1000, Encoding.IQ16)
    q = np.frombuffer(enc.data, "<i2") * enc.scale
    assert np.allclose(q, [1, 2, 3, 4], atol=enc.scale)


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name)
@pytest.mark.parametrize("shape", [(24000,), (2, 5001), (1,)], ids=["24k", "2ch", "one"])
def test_chunks_fit_reassemble_and_match_the_wire_estimate(
    encoding: Encoding, shape: tuple[int, ...]
) -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=shape)
    if encoding is Encoding.IQ16:
        x = x + 1j * rng.normal(size=shape)
    enc = encode_samples(x, 400000, encoding)
    chunks = chunk_echo(65535, enc)
    assert all(len(c.pack()) <= MAX_PAYLOAD for c in chunks)
    wire = b"".join(frame_bytes(MsgType.ECHO, i, 0, c.pack()) for i, c in enumerate(chunks))
    channels = 1 if len(shape) == 1 else shape[0]
    assert len(wire) <= echo_wire_bytes(shape[-1], channels, encoding)
    asm = EchoAssembler()
    outs = [asm.feed(EchoChunk.unpack(f.payload)) for f in FrameDecoder().feed(wire)]
    assert all(o is None for o in outs[:-1])
    echo = outs[-1]
    assert echo is not None and echo.ping_seq == 65535
    tol = 1e-6 if encoding is Encoding.FLOAT32 else enc.scale
    assert np.allclose(echo.samples, np.atleast_2d(x), atol=tol, rtol=1e-6)


def test_assembler_counts_gaps_duplicates_and_interleaving() -> None:
    enc = encode_samples(np.arange(6000.0), 400000, Encoding.INT16)
    a = chunk_echo(1, enc)
    b = chunk_echo(2, enc)
    assert len(a) == 3
    asm = EchoAssembler()
    # gap: chunk 1 missing
    assert asm.feed(a[0]) is None and asm.feed(a[2]) is None
    # duplicate chunk, then complete
    assert asm.feed(b[0]) is None and asm.feed(b[0]) is None
    assert asm.feed(b[1]) is None
    done = asm.feed(b[2])
    assert done is not None and done.ping_seq == 2
    # a new ping interrupts an unfinished echo
    assert asm.feed(a[0]) is None and asm.feed(b[0]) is None
    assert asm.stats() == {"echoes_complete": 1, "echoes_incomplete": 2, "chunk_duplicates": 1}


def test_link_budget_iq_20_pings_per_second_fits_921600() -> None:
    # a 20 Hz head listens at most 50 ms: 20000 samples at 400 kHz -> 1000 IQ at decimation 20
    b = link_budget(baudrate=921600, ping_rate_hz=20, echo_samples=20000,
                    encoding=Encoding.IQ16, decimation=20)
    assert b.fits and b.samples_per_echo == 1000
    assert b.framing_overhead <= 0.03
    assert b.capacity_bytes_per_s == 92160
    raw = link_budget(baudrate=921600, ping_rate_hz=20, echo_samples=20000,
                      encoding=Encoding.INT16)
    assert not raw.fits and raw.utilisation > 8
    with pytest.raises(ValueError, match="baudrate"):
        link_budget(baudrate=0, ping_rate_hz=1, echo_samples=1)
