"""Codec: hypothesis round trips for every message type and the byte layout of spec §1."""

from __future__ import annotations

import dataclasses
import math
import struct

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from hil_bridge.bus import codec
from hil_bridge.bus.messages import (
    REGISTRY,
    Clock,
    Diagnostics,
    GliderNeighbors,
    GliderState,
    Message,
    PointCloud,
    SonarEcho,
    message_class,
)
from hil_bridge.errors import CodecError

INT64 = st.integers(min_value=-(2**63), max_value=2**63 - 1)
UINT = st.integers(min_value=0, max_value=2**64 - 1)
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
TEXT = st.text(max_size=20)
SMALL = st.integers(min_value=0, max_value=6)


def _array(dtype: str, shape: st.SearchStrategy[tuple[int, ...]]) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(np.dtype(dtype), shape)


@st.composite
def _message(draw: st.DrawFn, cls: type[Message]) -> Message:
    import typing

    hints = typing.get_type_hints(cls)
    kwargs: dict[str, object] = {}
    k = draw(SMALL)
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        hint = hints[f.name]
        if f.name in cls.ARRAYS:
            dtype = cls.ARRAYS[f.name]
            if cls is SonarEcho and f.name != "samples":
                shape = (4,) if f.name == "orientation" else (3,)
            elif cls is SonarEcho:
                shape = draw(st.sampled_from([(k,), (2, k), (3, k + 1)]))
            elif cls is PointCloud:
                shape = (k, 3) if f.name == "points" else draw(st.sampled_from([(k,), (0,)]))
            else:
                shape = (k,)
            kwargs[f.name] = draw(_array(dtype, st.just(shape)))
        elif hint is int:
            kwargs[f.name] = draw(INT64)
        elif hint is float:
            kwargs[f.name] = draw(FLOATS)
        elif hint is bool:
            kwargs[f.name] = draw(st.booleans())
        elif hint is str:
            kwargs[f.name] = draw(TEXT)
        else:
            kwargs[f.name] = draw(
                st.dictionaries(TEXT, st.one_of(INT64, FLOATS), max_size=5)
            )
    return cls(**kwargs)


ALL_TYPES = sorted(REGISTRY.values(), key=lambda c: c.TYPE)


@pytest.mark.parametrize("cls", ALL_TYPES, ids=lambda c: c.TYPE)
@settings(max_examples=40, deadline=None)
@given(data=st.data(), seq=UINT, pub_ns=INT64, frame_id=TEXT)
def test_round_trip_every_type(
    cls: type[Message], data: st.DataObject, seq: int, pub_ns: int, frame_id: str
) -> None:
    msg = data.draw(_message(cls))
    frames = codec.encode("/a/b_1", msg, seq=seq, pub_ns=pub_ns, frame_id=frame_id, src="n#1")
    env = codec.decode(frames)
    assert env.msg == msg
    assert env.topic == "/a/b_1"
    assert env.header == codec.Header(
        msg.TYPE, msg.VERSION, seq, msg.stamp_ns, pub_ns, frame_id, "n#1"  # type: ignore[attr-defined]
    )
    for name in cls.ARRAYS:
        assert getattr(env.msg, name).dtype == np.dtype(cls.ARRAYS[name])


def test_byte_layout_matches_spec() -> None:
    samples = np.array([[1.0, -2.5], [0.25, 3.0]], dtype=np.float32)
    echo = SonarEcho(
        stamp_ns=7, ping_seq=3, fs=250e3, samples=samples, leaves_in_beam=11, fidelity="fast"
    )
    topic, header, payload = codec.encode(
        "/sonar/0/echo", echo, seq=5, pub_ns=99, frame_id="sonar0"
    )
    assert topic == b"/sonar/0/echo\x00"
    # header: a msgpack map whose first six keys are the spec's, in order
    h = msgpack.unpackb(header, raw=False)
    assert list(h)[:6] == ["type", "v", "seq", "stamp_ns", "pub_ns", "frame_id"]
    assert h["type"] == "echoloop/SonarEcho" and h["v"] == 1 and h["seq"] == 5
    assert h["stamp_ns"] == 7 and h["pub_ns"] == 99 and h["frame_id"] == "sonar0"
    assert header[0] == 0x87 and header[1:6] == b"\xa4type"  # fixmap of 7, fixstr "type"
    # payload: arrays are {dtype, shape, data} with bin data, little-endian C order
    p = msgpack.unpackb(payload, raw=False)
    for key in ("ping_seq", "fs", "samples", "leaves_in_beam", "fidelity"):
        assert key in p
    arr = p["samples"]
    assert arr == {"dtype": "<f4", "shape": [2, 2], "data": struct.pack("<4f", 1, -2.5, 0.25, 3)}
    assert b"\xc4\x10" + struct.pack("<4f", 1, -2.5, 0.25, 3) in payload  # bin 8, 16 bytes
    # a third-party decoder with plain msgpack sees the state fields of the spec
    state = GliderState(
        stamp_ns=1, x=1.0, y=2.0, z=3.0, heading=0.5, bank=-0.1, airspeed=9.0, vz=-0.7, alive=True
    )
    fields = msgpack.unpackb(codec.encode_payload(state), raw=False)
    keys = ("x", "y", "z", "heading", "bank", "airspeed", "vz", "alive")
    assert [fields[k] for k in keys] == [1.0, 2.0, 3.0, 0.5, -0.1, 9.0, -0.7, True]


def test_big_endian_input_array_is_sent_little_endian() -> None:
    ids = np.array([1, 2], dtype=">i4")
    nb = GliderNeighbors(
        stamp_ns=0, glider_id=0, ids=ids, x=np.zeros(2), y=np.zeros(2), z=np.zeros(2),
        heading=np.zeros(2), bank=np.zeros(2), airspeed=np.zeros(2), vz=np.zeros(2),
    )
    p = msgpack.unpackb(codec.encode_payload(nb), raw=False)
    assert p["ids"]["dtype"] == "<i4" and p["ids"]["data"] == struct.pack("<2i", 1, 2)


@pytest.mark.parametrize(
    "topic",
    ["", "/", "glider", "/glider/", "//glider", "/glider//0", "/glider-0", "/gl ider", "/é"],
)
def test_bad_topics_are_rejected(topic: str) -> None:
    with pytest.raises(ValueError, match="invalid topic"):
        codec.validate_topic(topic)


@given(st.lists(st.from_regex(r"[A-Za-z0-9_]{1,8}", fullmatch=True), min_size=1, max_size=5))
def test_topic_grammar_accepts_ros2_names(parts: list[str]) -> None:
    topic = "/" + "/".join(parts)
    assert codec.topic_from_frame(codec.topic_frame(topic)) == topic


def _frames() -> list[bytes]:
    return codec.encode("/clock", Clock(stamp_ns=5), seq=0, pub_ns=0)


def test_unknown_type_is_a_clear_codec_error() -> None:
    topic, header, payload = _frames()
    h = msgpack.unpackb(header)
    h["type"] = "other/Thing"
    with pytest.raises(CodecError, match=r"unknown message type 'other/Thing'.*echoloop/Clock"):
        codec.decode([topic, msgpack.packb(h), payload])


def test_newer_version_is_a_clear_codec_error() -> None:
    topic, header, payload = _frames()
    h = msgpack.unpackb(header)
    h["v"] = Clock.VERSION + 1
    with pytest.raises(CodecError, match="newer"):
        codec.decode([topic, msgpack.packb(h), payload])


def test_older_version_and_unknown_fields_decode() -> None:
    topic, header, _ = _frames()
    payload = msgpack.packb({"stamp_ns": 9, "added_later": [1, 2]})
    assert codec.decode([topic, header, payload]).msg == Clock(stamp_ns=9)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\xc1", "not valid msgpack"),
        (msgpack.packb([1, 2]), "must be a msgpack map"),
        (msgpack.packb({}), "does not fit"),
        (msgpack.packb({"stamp_ns": "soon"}), "expected int"),
        (msgpack.packb({"stamp_ns": True}), "expected int"),
    ],
    ids=["garbage", "list", "missing", "str", "bool"],
)
def test_bad_payloads_raise_codec_error(payload: bytes, reason: str) -> None:
    topic, header, _ = _frames()
    with pytest.raises(CodecError, match=reason):
        codec.decode([topic, header, payload])


@pytest.mark.parametrize(
    ("array", "reason"),
    [
        ({"dtype": "<f4", "shape": [3], "data": b"\0" * 8}, "needs 12"),
        ({"dtype": ">f4", "shape": [2], "data": b"\0" * 8}, "bad array map"),
        ({"dtype": "|O", "shape": [1], "data": b"\0" * 8}, "bad array map"),
        ({"dtype": "nonsense", "shape": [1], "data": b"\0"}, "unknown dtype"),
        ({"dtype": "<f4", "shape": [-1], "data": b""}, "bad array map"),
        ([1.0, 2.0], "expected an array map"),
    ],
    ids=["short", "big-endian", "object", "bad-dtype", "neg-shape", "list"],
)
def test_bad_arrays_raise_codec_error(array: object, reason: str) -> None:
    body = {"stamp_ns": 0, "ping_seq": 0, "fs": 1.0, "samples": array,
            "leaves_in_beam": 0, "fidelity": "fast"}
    with pytest.raises(CodecError, match=reason):
        codec.decode_payload("echoloop/SonarEcho", 1, msgpack.packb(body, use_bin_type=True))


def test_bad_header_and_frame_count() -> None:
    topic, _, payload = _frames()
    with pytest.raises(CodecError, match="misses key 'seq'"):
        codec.decode([topic, msgpack.packb({"type": "echoloop/Clock", "v": 1}), payload])
    with pytest.raises(CodecError, match="3 frames"):
        codec.decode([topic, payload])
    with pytest.raises(CodecError, match="3 frames"):
        codec.decode_topic_header([topic, _frames()[1]])
    name, header = codec.decode_topic_header(_frames())
    assert name == "/clock" and header.type == "echoloop/Clock" and header.stamp_ns == 5
    with pytest.raises(CodecError, match="NUL"):
        codec.decode([b"/clock", _frames()[1], payload])


def test_messages_are_immutable_and_arrays_read_only() -> None:
    src = np.ones(3, dtype=np.float32)
    echo = SonarEcho(stamp_ns=0, ping_seq=0, fs=1.0, samples=src, leaves_in_beam=0, fidelity="x")
    src[0] = 5.0
    assert echo.samples[0] == 1.0
    with pytest.raises(ValueError):
        echo.samples[0] = 2.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        echo.fs = 2.0
    with pytest.raises(ValueError, match="shape"):
        SonarEcho(stamp_ns=0, ping_seq=0, fs=1.0, samples=np.zeros((1, 2, 3)),
                  leaves_in_beam=0, fidelity="x")


def test_numpy_scalars_encode_as_plain_values() -> None:
    counters = {"a": np.int64(3), "b": np.float32(0.5)}
    diag = Diagnostics(stamp_ns=0, node="n", counters=counters)  # type: ignore[arg-type]
    out = codec.decode(codec.encode("/diagnostics", diag, seq=0, pub_ns=0)).msg
    assert isinstance(out, Diagnostics) and out.counters == {"a": 3, "b": 0.5}


def test_message_class_lookup_and_nan_equality() -> None:
    assert message_class("echoloop/GliderState") is GliderState
    with pytest.raises(CodecError, match="unknown message type"):
        message_class("echoloop/Nope")
    a = SonarEcho(stamp_ns=0, ping_seq=0, fs=math.nan, samples=np.array([math.nan]),
                  leaves_in_beam=0,
                  fidelity="x")
    assert a == codec.decode(codec.encode("/e", a, seq=0, pub_ns=0)).msg


_ANY = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats()
    | st.text(max_size=5) | st.binary(max_size=20),
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=5),
    max_leaves=15,
)
_ARRAYISH = st.fixed_dictionaries({
    "dtype": st.text(max_size=6) | st.sampled_from(["<f4", "<i4", "|b1", "<c8", "V8", "<U3", "O"]),
    "shape": st.lists(st.integers(-2, 2**40), max_size=3) | _ANY,
    "data": st.binary(max_size=16) | _ANY,
})
_FIELDS = st.sampled_from(["stamp_ns", "samples", "ping_seq", "fs", "fidelity", "leaves_in_beam",
                           "ids", "x", "counters", "node", "points", "intensity"])


@settings(max_examples=300, deadline=None)
@given(
    type_name=st.sampled_from(sorted(REGISTRY)),
    version=st.integers(-3, 3),
    seq=_ANY,
    payload=st.dictionaries(_FIELDS, _ANY | _ARRAYISH),
    garbage=st.binary(max_size=30),
    which=st.integers(0, 2),
)
def test_corrupt_frames_only_ever_raise_codec_error(
    type_name: str, version: int, seq: object, payload: dict[str, object], garbage: bytes,
    which: int,
) -> None:
    header = msgpack.packb({"type": type_name, "v": version, "seq": seq, "stamp_ns": 0,
                            "pub_ns": 0, "frame_id": ""}, use_bin_type=True)
    frames = [b"/a\0", header, msgpack.packb(payload, use_bin_type=True)]
    if which:
        frames[which] = garbage
    try:
        codec.decode(frames)
    except CodecError:
        pass


def _state_body() -> dict[str, object]:
    state = GliderState(stamp_ns=4, x=1.0, y=2.0, z=3.0, heading=0.1, bank=0.2, airspeed=9.0,
                        vz=-0.5, qw=1.0, qx=0.0, qy=0.0, qz=0.0)
    return msgpack.unpackb(codec.encode_payload(state))


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda b: dict(reversed(b.items())), None),  # another encoder's key order
        (lambda b: b | {"x": 1}, None),  # an int for a float
        (lambda b: b | {"added_later": 5}, None),
        (lambda b: b | {"x": True}, "expected float"),
        (lambda b: b | {"alive": 1}, "expected bool"),
        (lambda b: b | {"glider_id": 2.0}, "expected int"),
        (lambda b: {k: v for k, v in b.items() if k != "stamp_ns"}, "does not fit"),
    ],
    ids=["order", "int-for-float", "unknown-key", "bool-for-float", "int-for-bool",
         "float-for-int", "missing"],
)
def test_a_payload_off_the_usual_form_is_checked_field_by_field(change, expected) -> None:  # type: ignore[no-untyped-def]
    """The usual payload (every field, in wire order, each of its usual type) is taken at once;
    any other is checked field by field, as before."""
    body = change(_state_body())
    payload = msgpack.packb(body, use_bin_type=True)
    if expected is None:
        msg = codec.decode_payload("echoloop/GliderState", 1, payload)
        assert msg.x == body["x"] and msg.stamp_ns == 4
    else:
        with pytest.raises(CodecError, match=expected):
            codec.decode_payload("echoloop/GliderState", 1, payload)


def test_topic_frames_of_any_buffer_type_decode_alike() -> None:
    frame = codec.topic_frame("/glider/7/state")
    for buffer in (frame, bytearray(frame), memoryview(frame)):
        assert codec.topic_from_frame(buffer) == "/glider/7/state"  # type: ignore[arg-type]
    with pytest.raises(CodecError, match="bad topic frame"):
        codec.topic_from_frame(bytearray(b"/glider//7\0"))  # type: ignore[arg-type]
