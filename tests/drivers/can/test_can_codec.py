"""The glider CAN profile: DBC rules, every signal at its limits, saturation, counters that
wrap, node offsets."""

from __future__ import annotations

import itertools
import math

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.codec import (
    ANGLE_SIGNALS,
    COUNTER_SIGNALS,
    DBC_PATH,
    GliderCanCodec,
    SignalSpec,
    load_database,
    node_database,
)
from hil_bridge.errors import CodecError

CODEC = GliderCanCodec()
ALL_SIGNALS = [(m, s) for m in CODEC.message_names for s in CODEC.signals(m)]
IDS = [f"{m}.{s.name}" for m, s in ALL_SIGNALS]

#: docs/spec/protocols.md §3: binding names and the minimum resolution / range each must cover.
REQUIRED = {
    "GLIDER_STATE_POS": {
        "x_m": (0.01, -20000.0, 20000.0),
        "y_m": (0.01, -20000.0, 20000.0),
        "z_m": (0.01, 0.0, 5000.0),
    },
    "GLIDER_STATE_MOTION": {
        "heading_rad": (1e-4, -math.pi, math.pi),
        "bank_rad": (1e-4, -math.pi / 2, math.pi / 2),
        "airspeed_mps": (0.01, 0.0, 100.0),
        "vz_mps": (0.01, -50.0, 50.0),
    },
    "AUTOPILOT_CMD": {
        "bank_cmd_rad": (1e-4, -math.pi / 2, math.pi / 2),
        "airspeed_cmd_mps": (0.01, 0.0, 100.0),
    },
    # the attitude frames (issue 10): a quaternion to better than 1e-4 rad of rotation
    # (|error| <= 2 * sqrt(3) * scale / 2), body rates to 1e-4 rad/s over +-50 rad/s;
    # qw >= 0 (the one sign of the two quaternions of a rotation that is sent)
    "GLIDER_STATE_QUAT": {"qw": (5e-5, 0.0, 1.0)} | {
        q: (5e-5, -1.0, 1.0) for q in ("qx", "qy", "qz")},
    "GLIDER_STATE_RATES": {
        f"{axis}_rate_rps": (1e-4, -50.0, 50.0) for axis in ("roll", "pitch", "yaw")
    },
}


def _midpoints(message: str) -> dict[str, float]:
    return {s.name: (s.minimum + s.maximum) // 2 if s.name in COUNTER_SIGNALS
            else 0.5 * (s.minimum + s.maximum) for s in CODEC.signals(message)}


def _tol(sig_scale: float) -> float:
    return 0.5 * sig_scale + 1e-9


def test_dbc_follows_profile_rules() -> None:
    db = load_database(DBC_PATH)
    assert len(db.messages) == 9
    for msg in db.messages:
        assert not msg.is_extended_frame
        assert msg.frame_id % 0x10 == 0 and msg.frame_id + 15 <= 0x7FF
        assert msg.length == 8
        assert sum(s.length for s in msg.signals) <= 64
        for sig in msg.signals:
            assert sig.byte_order == "little_endian", sig.name
    bases = sorted(m.frame_id for m in db.messages)
    assert all(b - a >= 0x10 for a, b in itertools.pairwise(bases))


@pytest.mark.parametrize("message", sorted(REQUIRED))
def test_binding_signals_have_required_resolution_and_range(message: str) -> None:
    specs = {s.name: s for s in CODEC.signals(message)}
    for name, (resolution, lo, hi) in REQUIRED[message].items():
        sig = specs[name]
        assert sig.scale <= resolution, name
        assert sig.minimum <= lo + 1e-4 and sig.maximum >= hi - 1e-4, name
        # the raw field can hold every code of the range (no wrap inside the range)
        raw_max = (1 << (sig.bits - 1)) - 1 if sig.signed else (1 << sig.bits) - 1
        raw_min = -(1 << (sig.bits - 1)) if sig.signed else 0
        assert round(sig.maximum / sig.scale) <= raw_max
        assert round(sig.minimum / sig.scale) >= raw_min


@pytest.mark.parametrize(("message", "sig"), ALL_SIGNALS, ids=IDS)
def test_every_signal_at_its_limits(message: str, sig) -> None:  # type: ignore[no-untyped-def]
    codec = GliderCanCodec()
    for value in (sig.minimum, sig.maximum):
        values = _midpoints(message) | {sig.name: value}
        out = codec.decode(codec.encode(message, 0, values)).signals
        err = out[sig.name] - value
        if sig.name in ANGLE_SIGNALS:  # equal as angles (normalised to [-pi, pi))
            err = (err + math.pi) % (2 * math.pi) - math.pi
        assert abs(err) <= _tol(sig.scale), (value, out[sig.name])
    assert codec.saturation_counts() == {"tx": {}, "rx": {}}
    if sig.name in ANGLE_SIGNALS or sig.name in COUNTER_SIGNALS:
        return  # angles normalise, counters wrap: see test_angles_normalise, test_counters_wrap
    step = sig.scale  # one code outside the range: just outside
    for value, limit in ((sig.minimum - step, sig.minimum), (sig.maximum + step, sig.maximum)):
        values = _midpoints(message) | {sig.name: value}
        out = codec.decode(codec.encode(message, 0, values)).signals
        assert abs(out[sig.name] - limit) <= _tol(sig.scale)
    assert codec.saturation_counts()["tx"] == {sig.name: 2}


def test_angles_normalise() -> None:
    codec = GliderCanCodec()
    base = _midpoints("GLIDER_STATE_MOTION")
    for angle in (7.0, -7.0, 3 * math.pi, 100.0):
        out = codec.decode(codec.encode("GLIDER_STATE_MOTION", 0, base | {"heading_rad": angle}))
        diff = (out.signals["heading_rad"] - angle + math.pi) % (2 * math.pi) - math.pi
        assert abs(diff) <= 0.5e-4 + 1e-9
    assert codec.saturated_total == 0


@pytest.mark.parametrize("node", [0, 1, 7, 15])
def test_frame_id_is_base_plus_node(node: int) -> None:
    for name in CODEC.message_names:
        msg = CODEC.encode(name, node, _midpoints(name))
        assert msg.arbitration_id == CODEC.base_id(name) + node
        assert not msg.is_extended_id and msg.dlc == 8
        decoded = CODEC.decode(msg)
        assert (decoded.name, decoded.node_id) == (name, node)


@pytest.mark.parametrize("node", [-1, 16, 1.5, True])
def test_bad_node_id_is_refused(node: object) -> None:
    with pytest.raises(ValueError, match="node_id"):
        CODEC.frame_id("AUTOPILOT_CMD", node)  # type: ignore[arg-type]


def test_hand_computed_vector() -> None:
    # x = 1.00 m -> raw 100 at bits 0..21; y = -0.01 m -> raw -1 (22 ones) at bits 22..43;
    # z = 0.02 m -> raw 2 at bits 44..62. Little-endian: value = 100 | (2^22-1) << 22 | 2 << 44.
    msg = CODEC.encode("GLIDER_STATE_POS", 3, {"x_m": 1.0, "y_m": -0.01, "z_m": 0.02})
    expected = (100 | (((1 << 22) - 1) << 22) | (2 << 44)).to_bytes(8, "little")
    assert msg.arbitration_id == 0x123
    assert bytes(msg.data) == expected


def test_bad_values_and_signals_are_refused() -> None:
    with pytest.raises(ValueError, match="NaN"):
        CODEC.encode_payload("AUTOPILOT_CMD", {"bank_cmd_rad": math.nan, "airspeed_cmd_mps": 1,
                                               "cmd_counter": 0})
    with pytest.raises(ValueError, match="missing"):
        CODEC.encode_payload("AUTOPILOT_CMD", {"bank_cmd_rad": 0.0})
    with pytest.raises(ValueError, match="unknown signal"):
        CODEC.encode_payload("AUTOPILOT_CMD", {"bank_cmd_rad": 0.0, "airspeed_cmd_mps": 1,
                                               "cmd_counter": 0, "typo": 1})
    with pytest.raises(ValueError, match="unknown CAN message"):
        CODEC.encode_payload("NOPE", {})


def test_infinities_saturate() -> None:
    codec = GliderCanCodec()
    values = {"x_m": math.inf, "y_m": -math.inf, "z_m": 0.0}
    out = codec.decode(codec.encode("GLIDER_STATE_POS", 0, values)).signals
    assert out["x_m"] == pytest.approx(20000.0) and out["y_m"] == pytest.approx(-20000.0)
    assert codec.saturation_counts()["tx"] == {"x_m": 1, "y_m": 1}


@pytest.mark.parametrize(
    "msg",
    [
        can.Message(arbitration_id=0x120, data=bytes(7), is_extended_id=False),
        can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False),
        can.Message(arbitration_id=0x120, data=bytes(8), is_extended_id=True),
        can.Message(arbitration_id=0x120, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(arbitration_id=0x40, is_error_frame=True, data=bytes(8)),
        can.Message(arbitration_id=0x120, data=bytes(12), is_fd=True, is_extended_id=False),
    ],
    ids=["short", "unknown-id", "extended", "remote", "error", "fd"],
)
def test_frames_outside_the_profile_raise_codec_error(msg: can.Message) -> None:
    with pytest.raises(CodecError):
        CODEC.decode(msg)


def test_received_out_of_range_raw_saturates_and_counts() -> None:
    codec = GliderCanCodec()
    # z_m raw field of 19 bits can hold 5242.87 m; the range stops at 5000 m.
    raw = ((1 << 19) - 1) << 44
    out = codec.decode_payload(0x120, raw.to_bytes(8, "little"))
    assert out.signals["z_m"] == 5000.0
    assert codec.saturation_counts()["rx"] == {"z_m": 1}


finite = st.floats(allow_nan=False, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([(m, s) for m, s in ALL_SIGNALS
                        if s.name not in ANGLE_SIGNALS | COUNTER_SIGNALS]), finite)
def test_saturation_never_wraps(pair, value: float) -> None:  # type: ignore[no-untyped-def]
    message, sig = pair
    codec = GliderCanCodec()
    out = codec.decode(codec.encode(message, 5, _midpoints(message) | {sig.name: value}))
    got = out.signals[sig.name]
    clamped = min(max(value, sig.minimum), sig.maximum)
    assert sig.minimum <= got <= sig.maximum
    assert abs(got - clamped) <= _tol(sig.scale)
    outside = value < sig.minimum or value > sig.maximum
    assert codec.saturation_counts()["tx"].get(sig.name, 0) == int(outside)


COUNTERS = [(m, s) for m, s in ALL_SIGNALS if s.name in COUNTER_SIGNALS]


def test_the_state_frames_carry_the_sample_counter_where_a_bit_is_free() -> None:
    widths = {m: s.bits for m, s in COUNTERS if s.name == "state_counter"}
    assert widths == {"GLIDER_STATE_MOTION": 4, "GLIDER_STATE_QUAT": 1, "GLIDER_STATE_RATES": 4}
    # POS: x, y, z at the contract's resolution (63 bits) and the lockstep flag fill the frame
    assert [(s.name, s.bits) for s in CODEC.signals("GLIDER_STATE_POS")] == [
        ("x_m", 22), ("y_m", 22), ("z_m", 19), ("lockstep", 1)]


def test_quat_hand_computed_vector() -> None:
    # qw = 1 -> raw 20000 unsigned in bits 0..14; counter 7 -> its lowest bit, 1, in bit 15;
    # qx = -5e-5 -> raw -1 (16 ones) in bits 16..31; qy = qz = 0
    msg = CODEC.encode("GLIDER_STATE_QUAT", 2,
                       {"qw": 1.0, "qx": -5e-5, "qy": 0.0, "qz": 0.0, "state_counter": 7})
    assert bytes(msg.data) == (20000 | 1 << 15 | 0xFFFF << 16).to_bytes(8, "little")
    assert dict(CODEC.decode(msg).signals) == pytest.approx(
        {"qw": 1.0, "state_counter": 1.0, "qx": -5e-5, "qy": 0.0, "qz": 0.0})


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(COUNTERS), st.integers(-(2**40), 2**40))
def test_counters_round_trip_modulo_their_width(
    pair: tuple[str, SignalSpec], counter: int
) -> None:
    message, sig = pair
    codec = GliderCanCodec()
    values = _midpoints(message) | {sig.name: counter}
    out = codec.decode(codec.encode(message, 2, values)).signals
    assert out[sig.name] == counter % (1 << sig.bits)
    # a counter wraps, it never saturates, and it leaves the other signals alone
    assert codec.saturated_total == 0
    for other in CODEC.signals(message):
        if other.name != sig.name:
            assert abs(out[other.name] - values[other.name]) <= _tol(other.scale)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**20), st.integers(1, 40))
def test_sample_counter_wraps_alike_in_every_frame(start: int, n: int) -> None:
    """A sender counting on past 15 (and past any start): each frame carries the same counter
    modulo its width, so the frames of one sample agree and neighbouring samples differ."""
    got = []
    for counter in range(start, start + n):
        quat = CODEC.decode(CODEC.encode("GLIDER_STATE_QUAT", 1, _midpoints("GLIDER_STATE_QUAT")
                                         | {"state_counter": counter})).signals
        motion = CODEC.decode(CODEC.encode("GLIDER_STATE_MOTION", 1,
                                           _midpoints("GLIDER_STATE_MOTION")
                                           | {"state_counter": counter})).signals
        got.append((int(quat["state_counter"]), int(motion["state_counter"])))
        assert got[-1] == (counter % 2, counter % 16)
    assert all(a[0] != b[0] and (b[1] - a[1]) % 16 == 1 for a, b in itertools.pairwise(got))


@pytest.mark.parametrize("bad", [0.5, 2.25, math.inf, -math.inf])
def test_a_counter_must_be_an_integer(bad: float) -> None:
    with pytest.raises(ValueError, match="state_counter"):
        CODEC.encode_payload("GLIDER_STATE_RATES", _midpoints("GLIDER_STATE_RATES")
                             | {"state_counter": bad})


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_random_frames_decode_or_raise_codec_error(frame_id: int, data: bytes) -> None:
    try:
        out = CODEC.decode_payload(frame_id, data)
    except CodecError:
        return
    for sig in CODEC.signals(out.name):
        assert sig.minimum <= out.signals[sig.name] <= sig.maximum


def test_node_database_decodes_every_node_like_the_codec() -> None:
    import cantools

    expanded = cantools.database.load_string(node_database([0, 3, 15]).as_dbc_string(), "dbc")
    assert len(expanded.messages) == 3 * len(CODEC.message_names)
    for node in (0, 3, 15):
        for name in CODEC.message_names:
            msg = CODEC.encode(name, node, _midpoints(name))
            vendor = expanded.decode_message(msg.arbitration_id, bytes(msg.data),
                                             decode_choices=False)
            assert expanded.get_message_by_frame_id(msg.arbitration_id).name == f"{name}_N{node}"
            assert vendor == pytest.approx(dict(CODEC.decode(msg).signals))
    with pytest.raises(ValueError, match="node_id"):
        node_database([16])


@st.composite
def _in_range_values(draw: st.DrawFn) -> tuple[str, dict[str, float]]:
    """A message and a value for each of its signals, anywhere in (and a little beyond) its
    DBC range; counters any integer."""
    name = draw(st.sampled_from(CODEC.message_names))
    values: dict[str, float] = {}
    for sig in CODEC.signals(name):
        if sig.name in COUNTER_SIGNALS:
            values[sig.name] = draw(st.integers(-1000, 1000))
        else:
            span = sig.maximum - sig.minimum
            values[sig.name] = draw(st.floats(sig.minimum - 0.1 * span, sig.maximum + 0.1 * span))
    return name, values


@settings(max_examples=400, deadline=None)
@given(_in_range_values())
def test_frames_are_packed_as_cantools_packs_them(case: tuple[str, dict[str, float]]) -> None:
    """cantools is the oracle of the bit layout and the rounding: the codec's frame equals
    cantools' strict encode of the values contract 1 says are sent (angles normalised, ranges
    clamped, counters modulo their width), and decoding it gives cantools' physical values bit
    for bit."""
    name, values = case
    db = CODEC.database.get_message_by_name(name)
    sent: dict[str, float] = {}
    for sig in CODEC.signals(name):
        value = values[sig.name]
        if sig.name in COUNTER_SIGNALS:
            sent[sig.name] = int(value) % (1 << sig.bits)
            continue
        if sig.name in ANGLE_SIGNALS:
            value = (value + math.pi) % (2 * math.pi) - math.pi  # [-pi, pi)
            value = -math.pi if value >= math.pi else value
        sent[sig.name] = sig.clamp(value)
    payload = CODEC.encode_payload(name, values)
    assert payload == bytes(db.encode(sent, scaling=True, strict=True))
    decoded = CODEC.decode_payload(db.frame_id, payload).signals
    assert decoded == {k: float(v) for k, v in db.decode(payload, decode_choices=False).items()}


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(CODEC.message_names), st.binary(min_size=8, max_size=8))
def test_any_payload_decodes_as_cantools_decodes_it(name: str, data: bytes) -> None:
    """Every bit pattern: cantools' physical value, clamped to the DBC range."""
    db = CODEC.database.get_message_by_name(name)
    ours = CODEC.decode_payload(db.frame_id, data).signals
    for sig in CODEC.signals(name):
        raw = float(db.decode(data, decode_choices=False)[sig.name])
        assert ours[sig.name] == min(max(raw, sig.minimum), sig.maximum)


def test_a_dbc_the_packer_cannot_lay_out_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    text = DBC_PATH.read_text()
    motorola = text.replace(" : 0|16@1- (0.0001,0)", " : 7|16@0- (0.0001,0)", 1)
    assert motorola != text
    (tmp_path / "motorola.dbc").write_text(motorola)
    with pytest.raises(ValueError, match="Intel"):
        load_database(tmp_path / "motorola.dbc")
    narrow = text.replace("[-1.5708|1.5708]", "[-4|4]", 1)
    assert narrow != text
    (tmp_path / "narrow.dbc").write_text(narrow)
    with pytest.raises(ValueError, match="does not fit 16 bits"):
        GliderCanCodec(tmp_path / "narrow.dbc")
