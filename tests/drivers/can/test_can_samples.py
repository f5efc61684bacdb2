"""State samples over CAN: the sample counter on the wire, and an assembly that never mixes
two samples (drivers/can/samples.py, docs/can.md "Sample counter")."""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.adapter import AutopilotAdapter
from drivers.can.codec import DecodedFrame, GliderCanCodec
from drivers.can.samples import STATE_FRAMES, SampleAssembler, StateSample
from drivers.mocks.profile_receiver import ProfileReceiver
from hil_bridge.bus.messages import GliderState
from hil_bridge.bus.node import Node
from sim_core.pose import quat_from_euler
from tests.drivers.can._util import unique, wait_until

CODEC = GliderCanCodec()
POS, QUAT, RATES, MOTION = STATE_FRAMES
NODE = 4


def _truth(k: int) -> dict[str, float]:
    """The physical values of sample ``k``: every one a different function of ``k``, so a
    sample built from frames of two samples cannot match any one ``k``."""
    q = quat_from_euler(0.01 * k, -0.02 * k, 0.05 * k - 2.0)
    q = q if q[0] >= 0 else -q
    return {"x_m": 10.0 + k, "y_m": -3.0 * k, "z_m": 100.0 + 2.0 * k,
            "heading_rad": 0.05 * k - 2.0, "bank_rad": 0.001 * k, "airspeed_mps": 9.0 + 0.1 * k,
            "vz_mps": -0.01 * k, "qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
            "roll_rate_rps": 0.003 * k, "pitch_rate_rps": -0.002 * k,
            "yaw_rate_rps": 0.5 - 0.01 * k}


def _frames(k: int, *, attitude: bool = True, lockstep: bool = False,
            counter_start: int = 0) -> list[DecodedFrame]:
    """Sample ``k`` as a bridge sends it: POS, [QUAT, RATES,] MOTION, decoded back."""
    v, counter = _truth(k), counter_start + k
    values = {
        POS: {"x_m": v["x_m"], "y_m": v["y_m"], "z_m": v["z_m"], "lockstep": int(lockstep)},
        QUAT: {"qw": v["qw"], "qx": v["qx"], "qy": v["qy"], "qz": v["qz"],
               "state_counter": counter},
        RATES: {"roll_rate_rps": v["roll_rate_rps"], "pitch_rate_rps": v["pitch_rate_rps"],
                "yaw_rate_rps": v["yaw_rate_rps"], "state_counter": counter},
        MOTION: {"heading_rad": v["heading_rad"], "bank_rad": v["bank_rad"],
                 "airspeed_mps": v["airspeed_mps"], "vz_mps": v["vz_mps"], "alive": 1,
                 "state_counter": counter},
    }
    names = STATE_FRAMES if attitude else (POS, MOTION)
    return [CODEC.decode(CODEC.encode(n, NODE, values[n])) for n in names]


def _which(sample: StateSample) -> int:
    """The one sample ``k`` all of ``sample``'s values come from (fails if there is none)."""
    k = round(sample.x - 10.0)
    v = _truth(k)
    got = {"x_m": sample.x, "y_m": sample.y, "z_m": sample.z, "heading_rad": sample.heading,
           "bank_rad": sample.bank, "airspeed_mps": sample.airspeed, "vz_mps": sample.vz}
    if sample.attitude is not None:
        got |= dict(zip(("qw", "qx", "qy", "qz"), sample.attitude, strict=True))
    if sample.body_rates is not None:
        got |= dict(zip(("roll_rate_rps", "pitch_rate_rps", "yaw_rate_rps"), sample.body_rates,
                        strict=True))
    for name, value in got.items():
        assert value == pytest.approx(v[name], abs=1e-4), (k, name)
    return k


def _feed(frames: list[DecodedFrame]) -> tuple[list[int], SampleAssembler]:
    asm = SampleAssembler(CODEC)
    delivered = [_which(s) for f in frames if (s := asm.feed(f)) is not None]
    return delivered, asm


N = 24
#: (frame lost, whether the sample carries an attitude): every frame a sample can lose
LOSSES = [(lost, True) for lost in STATE_FRAMES] + [(POS, False), (MOTION, False)]


@pytest.mark.parametrize("k", [1, 7, 16])  # 16: the counter has wrapped to 0
@pytest.mark.parametrize(("lost", "attitude"), LOSSES,
                         ids=[f"{n}-{'att' if a else 'no-att'}" for n, a in LOSSES])
def test_losing_any_one_frame_never_mixes_two_samples(lost: str, attitude: bool, k: int) -> None:
    frames = [f for i in range(N) for f in _frames(i, attitude=attitude)
              if not (i == k and f.name == lost)]
    delivered, asm = _feed(frames)
    # sample 0 only binds the counter; sample k is torn, and counted; every other one arrives
    assert delivered == [i for i in range(1, N) if i != k]
    assert asm.counters == {"states": N - 2, "samples_torn": 1, "samples_unverified": 1}


def test_without_loss_every_sample_after_the_first_arrives() -> None:
    frames = [f for i in range(N) for f in _frames(i, attitude=i % 3 != 0)]
    delivered, asm = _feed(frames)
    assert delivered == list(range(1, N))
    assert asm.counters == {"states": N - 1, "samples_unverified": 1}


def test_a_whole_lost_sample_costs_the_next_one_its_binding() -> None:
    """After a sample lost whole, the next POS could be either sample's: it is not trusted."""
    frames = [f for i in range(N) if i != 5 for f in _frames(i)]
    delivered, asm = _feed(frames)
    assert delivered == [i for i in range(1, N) if i not in (5, 6)]
    assert asm.counters["samples_unverified"] == 2 and asm.counters["samples_torn"] == 0


def test_an_earlier_samples_position_is_not_taken() -> None:
    """POS of sample 3 survives, the rest of 3 and the POS of 4 are lost: 4's QUAT, RATES and
    MOTION follow 3's POS in order and agree among themselves, but the count of POS frames
    since sample 2 (one) does not reach 4's counter: dropped, never delivered as sample 4."""
    frames = [f for i in range(N) for f in _frames(i)
              if not (i == 3 and f.name != POS) and not (i == 4 and f.name == POS)]
    delivered, asm = _feed(frames)
    assert delivered == [i for i in range(1, N) if i not in (3, 4)]
    assert asm.counters["samples_unverified"] == 2 and asm.counters["samples_torn"] == 0


def test_duplicates_are_ignored_and_reordered_frames_tear() -> None:
    frames = [f for i in range(6) for f in _frames(i)]
    doubled = [g for f in frames for g in ((f, f) if f.name in (POS, RATES) else (f,))]
    delivered, asm = _feed(doubled)
    assert delivered == [1, 2, 3, 4, 5] and asm.counters["state_frames_duplicate"] == 12


def _reordered(order: list[str]) -> list[DecodedFrame]:
    """Samples 0..5, sample 3's frames in ``order``."""
    return [f for i in range(6) for f in sorted(
        _frames(i), key=lambda f, i=i: order.index(f.name) if i == 3 else 0)]


def test_frames_out_of_order_tear_their_sample() -> None:
    # RATES before QUAT: QUAT cannot follow RATES, and what is left has no POS
    delivered, asm = _feed(_reordered([POS, RATES, QUAT, MOTION]))
    assert delivered == [1, 2, 4, 5] and asm.counters["samples_torn"] == 2
    # a transmit queue sorted by id sends MOTION (0x130) before QUAT and RATES: the sample
    # completes without its attitude, and the attitude frames after it are dropped, counted
    asm = SampleAssembler(CODEC)
    got = [s for f in _reordered([POS, MOTION, QUAT, RATES]) if (s := asm.feed(f)) is not None]
    assert [_which(s) for s in got] == [1, 2, 3, 4, 5]
    assert got[2].attitude is None and got[2].body_rates is None
    assert asm.counters["samples_torn"] == 1


@pytest.mark.parametrize("late", [(QUAT,), (QUAT, RATES)], ids=["quat", "quat+rates"])
def test_attitude_frames_late_into_the_next_sample_are_caught_by_their_counter(
    late: tuple[str, ...]
) -> None:
    """A transmit queue with few mailboxes, sorted by id, can send sample 3's attitude frames
    after sample 4's POS; sample 4's own attitude frames of the same kind are lost. In order,
    and with one POS since the last MOTION, only the counters (QUAT's lowest bit, RATES' four)
    tell that they are not sample 4's."""
    frames: list[DecodedFrame] = []
    for i in range(8):
        sample = _frames(i)
        if i == 3:
            held = [f for f in sample if f.name in late]
            sample = [f for f in sample if f.name not in late]
        elif i == 4:
            sample = [sample[0], *held, *(f for f in sample[1:] if f.name not in late)]
        frames += sample
    delivered, asm = _feed(frames)
    # sample 3 without its QUAT is torn; without both attitude frames it is whole (no attitude)
    assert delivered == ([1, 2, 5, 6, 7] if late == (QUAT,) else [1, 2, 3, 5, 6, 7])
    assert asm.counters["samples_torn"] == (3 if late == (QUAT,) else 2)


def test_frames_of_another_node_do_not_interfere() -> None:
    asm = SampleAssembler(CODEC)
    other = [DecodedFrame(f.name, NODE + 1, f.signals) for i in range(10) for f in _frames(50 + i)]
    mine = [f for i in range(10) for f in _frames(i)]
    got = [s for a, b in zip(mine, other, strict=True) for f in (a, b)
           if (s := asm.feed(f)) is not None]
    assert sorted((s.node_id, _which(s)) for s in got) == (
        [(NODE, i) for i in range(1, 10)] + [(NODE + 1, 50 + i) for i in range(1, 10)])


@settings(max_examples=300, deadline=None)
@given(
    attitude=st.lists(st.booleans(), min_size=16, max_size=16),
    start=st.integers(0, 15),
    ops=st.lists(st.sampled_from(["keep", "keep", "keep", "drop", "dup", "swap"]),
                 min_size=64, max_size=64),
)
def test_no_corruption_of_the_stream_yields_a_mixed_sample(
    attitude: list[bool], start: int, ops: list[str]
) -> None:
    """Any frames lost, any frame repeated, the frames after POS swapped inside a sample:
    every sample delivered is one sent, whole, each at most once and in order. (POS leads its
    sample in any transmit queue, FIFO or by id; 16 samples: a gap of 16 would alias the
    4-bit counter.)"""
    frames: list[DecodedFrame] = []
    for i, has_att in enumerate(attitude):
        sample = _frames(i, attitude=has_att, counter_start=start)
        for j in range(len(sample)):
            op = ops[(4 * i + j) % len(ops)]
            if op == "swap" and 1 <= j < len(sample) - 1:
                sample[j], sample[j + 1] = sample[j + 1], sample[j]
        for j, f in enumerate(sample):
            op = ops[(4 * i + j) % len(ops)]
            frames += [] if op == "drop" else [f, f] if op == "dup" else [f]
    delivered, _ = _feed(frames)
    assert delivered == sorted(set(delivered))
    if all(op == "keep" for op in ops):
        assert delivered == list(range(1, 16))


def test_the_mocks_view_never_shows_two_samples_at_once() -> None:
    """The mock's receiver, frame by frame, with sample 3's QUAT lost: at no moment does its
    view pair one sample's attitude or rates with another's position."""
    rx = ProfileReceiver([NODE])
    for f in [f for i in range(8) for f in _frames(i) if not (i == 3 and f.name == QUAT)]:
        rx.feed(f, 1.0)
        view = rx.view(NODE)
        if view.own is None:
            continue
        k = round(view.own.x - 10.0)
        v = _truth(k)
        assert view.state_counter == k and view.own.heading == pytest.approx(v["heading_rad"],
                                                                               abs=1e-4)
        np.testing.assert_allclose(view.attitude, [v[q] for q in ("qw", "qx", "qy", "qz")],
                                   atol=1e-4)
        np.testing.assert_allclose(view.body_rates, [v["roll_rate_rps"], v["pitch_rate_rps"],
                                                     v["yaw_rate_rps"]], atol=1e-4)
    counts = rx.counts()
    assert counts["states"] == 6 and counts["samples_torn"] == 1
    assert counts["samples_unverified"] == 1


@pytest.fixture
def adapter_wire() -> Iterator[tuple[Node, can.BusABC]]:
    bus, channel = f"mem://{unique('smp-')}", unique("smpch-")
    sim = Node("sim", bus=bus, diagnostics_period_s=0)
    wire = can.Bus(interface="virtual", channel=channel)
    adapter = AutopilotAdapter("autopilot", bus=bus, channel=channel, gliders={7: NODE},
                               state_rate_hz=100.0)
    sim.start()
    adapter.start()
    yield sim, wire
    adapter.stop()
    sim.stop()
    wire.shutdown()


def test_the_adapter_puts_the_counter_on_every_frame_that_has_room(
    adapter_wire: tuple[Node, can.BusABC]
) -> None:
    sim, wire = adapter_wire
    pub = sim.create_publisher(GliderState, "/glider/7/state")
    q = quat_from_euler(0.3, -0.1, 3.0)
    assert q[0] > 0
    # published with qw < 0: the same rotation goes out as +q (qw >= 0), nothing saturates
    pub.publish(GliderState(stamp_ns=1, x=1.0, y=2.0, z=3.0, heading=3.0, bank=-0.3,
                            airspeed=10.0, vz=0.0, qw=-q[0], qx=-q[1], qy=-q[2], qz=-q[3],
                            roll_rate=0.1, pitch_rate=0.0, yaw_rate=0.2))
    seen: list[DecodedFrame] = []

    def motions() -> int:
        while (msg := wire.recv(0.0)) is not None:
            frame = CODEC.decode(msg)
            if frame.name in STATE_FRAMES:
                seen.append(frame)
        return sum(f.name == MOTION for f in seen)

    assert wait_until(lambda: motions() >= 20)
    start = [f.name for f in seen].index(POS)
    samples = [seen[i:i + 4] for i in range(start, len(seen) - 3, 4)]
    counters = []
    for pos, quat, rates, motion in samples:
        assert [pos.name, quat.name, rates.name, motion.name] == list(STATE_FRAMES[:4])
        c = int(motion.signals["state_counter"])
        assert int(rates.signals["state_counter"]) == c
        assert int(quat.signals["state_counter"]) == c % 2
        np.testing.assert_allclose([quat.signals[n] for n in ("qw", "qx", "qy", "qz")], q,
                                   atol=2.5e-5 + 1e-9)
        counters.append(c)
    assert len(counters) >= 15
    assert all((b - a) % 16 == 1 for a, b in itertools.pairwise(counters))
