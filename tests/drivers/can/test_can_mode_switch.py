"""The adapter's frames at mode switches: however ``/clock`` switches between free-running and
lockstep while samples flow, every sample goes out whole and alone (docs/can.md, "Lockstep").

The adapter's two senders are driven by hand from two threads, as its transmit thread (the
periodic samples and heartbeats) and its node executor (``/clock``, states, neighbour lists) run
them, on a seeded random schedule; every frame is read back from the virtual bus."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Iterator, Mapping

import can
import numpy as np
import pytest

from drivers.can.adapter import AutopilotAdapter
from drivers.can.codec import DecodedFrame, GliderCanCodec
from drivers.can.samples import SampleAssembler
from hil_bridge.bus.codec import Envelope, Header
from hil_bridge.bus.messages import Clock, GliderNeighbors, GliderState
from tests.drivers.can._util import unique, wait_until

CODEC = GliderCanCodec()
NODES = {3: 0, 5: 1}
STEPS = 200


def _state(gid: int, step: int) -> Envelope:
    msg = GliderState(stamp_ns=step * 4_000_000, glider_id=gid, step=step, x=float(step),
                      y=-2.0 * gid, z=300.0 + step, heading=0.01 * step, bank=0.1,
                      airspeed=10.0, vz=-0.5, qw=1.0, qx=0.0, qy=0.0, qz=0.0, roll_rate=0.0,
                      pitch_rate=0.0, yaw_rate=0.02)
    return Envelope(f"/glider/{gid}/state",
                    Header(GliderState.TYPE, GliderState.VERSION, step, msg.stamp_ns,
                           time.monotonic_ns()), msg, b"")


def _neighbours(gid: int, step: int, k: int) -> GliderNeighbors:
    ids = np.arange(k, dtype=np.int32) + 10
    return GliderNeighbors(stamp_ns=step * 4_000_000, glider_id=gid, ids=ids, x=ids + 5.0,
                           y=ids * 0.0, z=ids + 300.0, heading=ids * 0.1, bank=ids * 0.0,
                           airspeed=ids * 0.0 + 10.0, vz=ids * 0.0, step=step)


@pytest.fixture
def adapter() -> Iterator[tuple[AutopilotAdapter, can.BusABC]]:
    channel = unique("modes-")
    receiver = can.Bus(interface="virtual", channel=channel)
    ad = AutopilotAdapter("autopilot", bus=f"mem://{unique('modes-')}", channel=channel,
                          gliders=dict(NODES), state_timeout_s=1e6, neighbor_rate_hz=1e6,
                          diagnostics_period_s=0)
    assert ad.can.open()
    send = ad.can.send

    def send_and_yield(name: str, node: int, values: Mapping[str, float]) -> bool:
        ok = send(name, node, values)
        time.sleep(0)  # hand the GIL to the other sender between any two frames
        return ok

    ad.can.send = send_and_yield  # type: ignore[method-assign]
    yield ad, receiver
    ad.stop()
    receiver.shutdown()


def _executor(ad: AutopilotAdapter, rng: np.random.Generator, start: threading.Barrier,
              done: threading.Event) -> tuple[int, int]:
    """The node executor's side: ``/clock`` switching mode, states and neighbour lists; in
    free-running steps it lets the transmitter send 1-3 samples first. The steps run in
    lockstep and the free-running samples waited for."""
    on_state = {gid: ad._make_state_cb(gid) for gid in NODES}
    on_nbs = {gid: ad._make_nb_cb(gid) for gid in NODES}
    lockstep, lockstep_steps, free_samples = False, 0, 0
    start.wait()
    try:
        for step in range(1, STEPS + 1):
            if rng.random() < 0.2:
                lockstep = not lockstep
                ad._on_clock(Clock(stamp_ns=step * 4_000_000, lockstep=lockstep))
            for gid in rng.permutation(list(NODES)):
                if rng.random() < 0.5:
                    on_nbs[gid](_neighbours(int(gid), step, int(rng.integers(0, 4))))
                on_state[gid](_state(int(gid), step))
            if lockstep:
                lockstep_steps += 1
            else:
                free_samples += int(rng.integers(1, 4))
                assert wait_until(_sent_at_least(ad, free_samples))
    finally:
        done.set()
    return lockstep_steps, free_samples


def _sent_at_least(ad: AutopilotAdapter, n: int) -> Callable[[], bool]:
    return lambda: int(ad.counters().get("states_sent", 0)) >= n


def _transmitter(ad: AutopilotAdapter, rng: np.random.Generator, start: threading.Barrier,
                 done: threading.Event) -> None:
    """The transmit thread's side, while the executor runs: every call a slot due, now and then
    the heartbeats."""
    slot_s = 1.0 / (ad.state_rate_hz * len(ad._slots))
    ad._start_wall = 0.0
    start.wait()
    k = 0
    while not done.is_set():
        ad._send_states(k * slot_s)
        k += 1
        if rng.random() < 0.1:
            ad._send_heartbeats()
        time.sleep(0)


def _units(frames: list[DecodedFrame]) -> list[list[DecodedFrame]]:
    """The frames cut into what was sent as one: a sample (with its neighbour list) or a
    heartbeat. Fails on any frame out of its place."""
    units: list[list[DecodedFrame]] = []
    i = 0
    while i < len(frames):
        first = frames[i]
        if first.name == "BRIDGE_HEARTBEAT":
            units.append([first])
            i += 1
            continue
        assert first.name == "GLIDER_STATE_POS", f"frame {i}: {first.name} starts no sample"
        lockstep = bool(first.signals["lockstep"])
        unit, i = [first], i + 1
        if lockstep:
            nbs = _neighbour_list(frames, i, first.node_id)
            unit += nbs
            i += len(nbs)
        want = ["GLIDER_STATE_QUAT", "GLIDER_STATE_RATES", "GLIDER_STATE_MOTION"]
        got = frames[i:i + 3]
        assert [(f.name, f.node_id) for f in got] == [(n, first.node_id) for n in want], (
            f"frame {i}: sample of node {first.node_id} broken by {got}")
        unit += got
        i += 3
        if not lockstep:
            nbs = _neighbour_list(frames, i, first.node_id)
            unit += nbs
            i += len(nbs)
        units.append(unit)
    return units


def _neighbour_list(frames: list[DecodedFrame], i: int, node: int) -> list[DecodedFrame]:
    """The neighbour list of ``node`` starting at frame ``i`` (none: []), checked whole."""
    if i >= len(frames) or not frames[i].name.startswith("NEIGHBOR_"):
        return []
    out: list[DecodedFrame] = []
    while i + len(out) < len(frames) and frames[i + len(out)].name.startswith("NEIGHBOR_"):
        f = frames[i + len(out)]
        assert f.node_id == node, f"frame {i + len(out)}: node {f.node_id} inside {node}'s list"
        out.append(f)
        if f.name == "NEIGHBOR_MOTION" and f.signals["nb_slot"] >= f.signals["nb_count"] - 1:
            break
    count = int(out[-1].signals["nb_count"])
    names = ["NEIGHBOR_MOTION"] if count == 0 else ["NEIGHBOR_POS", "NEIGHBOR_MOTION"] * count
    assert [f.name for f in out] == names, f"frame {i}: torn neighbour list {out}"
    sets = {f.signals["nb_set"] for f in out if f.name == "NEIGHBOR_MOTION"}
    assert len(sets) == 1, f"frame {i}: two lists mixed"
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_sample_goes_out_whole_at_every_mode_switch(
    adapter: tuple[AutopilotAdapter, can.BusABC], seed: int
) -> None:
    ad, receiver = adapter
    rngs = np.random.default_rng(seed).spawn(2)
    start, done = threading.Barrier(2), threading.Event()
    transmitter = threading.Thread(target=_transmitter, args=(ad, rngs[1], start, done))
    transmitter.start()
    try:
        lockstep_steps, free_samples = _executor(ad, rngs[0], start, done)
    finally:
        transmitter.join()
    frames = []
    while (msg := receiver.recv(0.0)) is not None:
        frames.append(CODEC.decode(msg))
    units = _units(frames)
    samples = [u for u in units if u[0].name == "GLIDER_STATE_POS"]
    modes = [bool(u[0].signals["lockstep"]) for u in samples]
    switches = sum(a != b for a, b in itertools.pairwise(modes))
    assert modes.count(True) == len(NODES) * lockstep_steps > 100
    assert modes.count(False) >= free_samples > 100
    assert switches > 20
    assembler = SampleAssembler()
    for f in frames:
        if f.name.startswith("GLIDER_STATE_"):
            assembler.feed(f)
    assert assembler.counters["samples_torn"] == 0
    assert assembler.counters["samples_unverified"] == len(NODES)  # each node's first
    assert assembler.counters["states"] == len(samples) - len(NODES)
    assert ad.counters().get("states_dropped", 0) == 0
