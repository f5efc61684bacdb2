"""CAN glider profile: frames/s and bus load for 8 gliders at 50 Hz, codec cost, fuzzing.

1. A closed loop (SimServer with an 8-glider swarm at 50 Hz state, AutopilotAdapter, the mock
   autopilot flying all 8 at 50 Hz) runs on a python-can ``virtual`` bus with a candump log;
   frames/s per message come from the log, and the load of a 1 Mbit/s bus from each logged
   frame's exact on-wire length (CRC-15 and bit stuffing computed) and from the 135-bit worst
   case. A table adds the load of heavier configurations computed from the frame rates.
2. Encode/decode cost per frame of the saturating codec against bare cantools.
3. Fuzzing: random frames (profile ids and others, any length, extended/remote/error flags)
   through the decoder and the autopilot's frame assembly; every exception other than the
   codec's ``CodecError`` would be a crash.
"""

from __future__ import annotations

import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import can
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from bench._util import fmt_s, median, table, time_it
from drivers.can.adapter import AutopilotAdapter
from drivers.can.busload import frame_bits, worst_case_bits
from drivers.can.codec import GliderCanCodec
from drivers.faults.can_bus import FaultInjectingBus
from drivers.mocks.autopilot import MockAutopilot
from drivers.mocks.path_follower import figure_eight_waypoints
from drivers.mocks.profile_receiver import ProfileReceiver
from hil_bridge.bus.messages import GliderCmd, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.errors import CodecError
from hil_bridge.server.sim_server import SimServer

TITLE = "CAN glider autopilot (drivers.can)"

N_GLIDERS = 8
RATE_HZ = 50.0
RUN_S = 8.0
BITRATE = 1_000_000
WORST = worst_case_bits(8)


def _closed_loop(log_path: Path) -> tuple[list[can.Message], dict[str, Any]]:
    bus = "mem://bench_can"
    scene = {"seed": 3, "state_rate_hz": RATE_HZ, "clock": {"mode": "realtime", "rate": 1.0},
             "swarm": {"law": "default", "overrides": {"numAgents": N_GLIDERS}}}
    server = SimServer("server", bus=bus, scene=scene)
    adapter = AutopilotAdapter("autopilot", bus=bus, channel="bench_can",
                               gliders=list(range(N_GLIDERS)), state_rate_hz=RATE_HZ,
                               can_log=str(log_path))
    mock = MockAutopilot("mock", channel="bench_can", gliders=list(range(N_GLIDERS)),
                         rate_hz=RATE_HZ)
    server.start()
    adapter.start()
    mock.start()
    time.sleep(RUN_S)
    stats = {k: v for k, v in adapter.stats().items() if isinstance(v, int | float | str)}
    stats |= {f"mock_{k}": v for k, v in mock.stats().items() if isinstance(v, int | float)}
    mock.stop()
    adapter.stop()
    server.stop()
    return list(can.LogReader(log_path)), stats


def _bus_load(out_dir: Path) -> str:
    codec = GliderCanCodec()
    names = {codec.base_id(n): n for n in codec.message_names}
    with tempfile.TemporaryDirectory() as tmp:
        frames, stats = _closed_loop(Path(tmp) / "bench.log")
    data = [m for m in frames if not m.is_error_frame]
    t0, t1 = data[0].timestamp, data[-1].timestamp
    span = t1 - t0
    count: Counter[str] = Counter()
    bits: Counter[str] = Counter()
    for m in data:
        name = names.get(m.arbitration_id & ~0xF, "other")
        count[name] += 1
        bits[name] += frame_bits(m.arbitration_id, bytes(m.data))
    rows = []
    for name in codec.message_names:
        if count[name]:
            rows.append([name, f"{count[name] / span:.0f}", f"{bits[name] / count[name]:.1f}",
                         f"{100 * bits[name] / span / BITRATE:.1f} %",
                         f"{100 * count[name] * WORST / span / BITRATE:.1f} %"])
    total_f = sum(count.values()) / span
    total_typ = 100 * sum(bits.values()) / span / BITRATE
    total_worst = 100 * sum(count.values()) * WORST / span / BITRATE
    mean_bits = sum(bits.values()) / sum(count.values())
    rows.append(["**total**", f"**{total_f:.0f}**", f"{mean_bits:.1f}",
                 f"**{total_typ:.1f} %**", f"**{total_worst:.1f} %**"])
    measured = table(
        ["message", "frames/s", "mean bits/frame (stuffed)", "load, actual stuffing",
         "load, worst case (135 bit)"], rows)

    def load(per_glider_fps: float) -> str:
        return f"{100 * N_GLIDERS * per_glider_fps * WORST / BITRATE:.1f} %"

    # per glider and second: 4 state frames (position, motion, attitude, rates) per sample
    base = 4 * 50 + 50 + 20
    configs = [
        ("state 50 Hz (4 frames), cmd 50 Hz, heartbeats 10 Hz both ways, no neighbours", base),
        ("+ 10 neighbours (seed k) per list at 2 Hz (one list per control step)",
         base + 2 * 10 * 2),
        ("+ 10 neighbours at the 10 Hz cap (`neighbor_rate_hz`)", base + 2 * 10 * 10),
        ("+ 15 neighbours (profile maximum) at 10 Hz", base + 2 * 15 * 10),
        ("state without the attitude frames (2 frames), 10 neighbours at 10 Hz",
         2 * 50 + 50 + 20 + 2 * 10 * 10),
    ]
    cfg_rows = [[c, f"{N_GLIDERS * f}", load(f)] for c, f in configs]
    computed = table(["configuration (8 gliders)", "frames/s", "worst-case load, 1 Mbit/s"],
                     cfg_rows)

    fig, ax = plt.subplots(figsize=(7, 3.2))
    labels = [r[0] for r in rows[:-1]]
    typ = [100 * bits[n] / span / BITRATE for n in labels]
    worst = [100 * count[n] * WORST / span / BITRATE for n in labels]
    y = np.arange(len(labels))
    ax.barh(y - 0.2, typ, 0.4, label="actual stuffing")
    ax.barh(y + 0.2, worst, 0.4, label="worst case")
    ax.set_yticks(y, labels)
    ax.set_xlabel("share of a 1 Mbit/s bus (%)")
    ax.set_title(f"{N_GLIDERS} gliders at {RATE_HZ:g} Hz: total {total_typ:.1f} % "
                 f"(worst {total_worst:.1f} %)")
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(out_dir / "can_bus_load.png", dpi=110)
    plt.close(fig)

    return (
        f"### Bus load: {N_GLIDERS} gliders at {RATE_HZ:g} Hz\n\n"
        f"Closed loop for {RUN_S:g} s (SimServer swarm, `AutopilotAdapter`, `MockAutopilot` "
        f"commanding all {N_GLIDERS} at {RATE_HZ:g} Hz; neighbour lists arrive once per control "
        f"step, 2 Hz). {len(data)} frames logged over {span:.2f} s; commands forwarded "
        f"{stats.get('cmd_forwarded', 0)}, link `{stats.get('can_link')}`; the mock assembled "
        f"{stats.get('mock_rx_states', 0)} state samples, dropped "
        f"{stats.get('mock_rx_samples_torn', 0)} torn and "
        f"{stats.get('mock_rx_samples_unverified', 0)} unverified (docs/can.md, sample "
        f"counter). Goal: ≤ 50 % of a 1 Mbit/s bus.\n\n{measured}\n\n"
        f"From frame rates, worst-case stuffing:\n\n{computed}\n\n"
        "![CAN bus load](docs/figures/bench/can_bus_load.png)\n"
    )


def _codec_cost() -> str:
    codec = GliderCanCodec()
    samples = {
        "GLIDER_STATE_POS": {"x_m": 1234.56, "y_m": -987.65, "z_m": 1500.25},
        "GLIDER_STATE_MOTION": {"heading_rad": 1.2345, "bank_rad": -0.2, "airspeed_mps": 10.5,
                                "vz_mps": -0.55, "alive": 1, "state_counter": 7},
        "GLIDER_STATE_QUAT": {"qw": 0.9, "qx": 0.1, "qy": -0.3, "qz": 0.3, "state_counter": 7},
        "AUTOPILOT_CMD": {"bank_cmd_rad": 0.25, "airspeed_cmd_mps": 11.2, "cmd_counter": 9},
    }
    n = 2000
    rows = []
    for name, values in samples.items():
        raw = codec.database.get_message_by_name(name)
        msg = codec.encode(name, 3, values)
        payload = bytes(msg.data)
        # every signal of the frame, as the codec fills them (cantools' strict encode wants all)
        full = raw.decode(payload, decode_choices=False)

        def per_frame(fn: Callable[[], object]) -> float:
            return median(time_it(lambda: [fn() for _ in range(n)], repeat=5)) / n

        enc = per_frame(partial(codec.encode, name, 3, values))
        base_enc = per_frame(partial(raw.encode, full, strict=True))
        dec = per_frame(partial(codec.decode, msg))
        base_dec = per_frame(partial(raw.decode, payload, decode_choices=False))
        rows.append([name, fmt_s(enc), fmt_s(base_enc), f"{enc / base_enc:.2f}×",
                     fmt_s(dec), fmt_s(base_dec), f"{dec / base_dec:.2f}×"])
    return (
        "### Codec cost per frame\n\n"
        "`GliderCanCodec` (range check, saturation counting, node offset, python-can Message) "
        "against bare cantools `Message.encode(strict=True)` / `decode` of the same payload; "
        f"medians of 5 batches of {n}.\n\n"
        + table(["message", "encode", "cantools encode", "ratio", "decode", "cantools decode",
                 "ratio"], rows)
        + "\n"
    )


def _fuzz() -> str:
    codec = GliderCanCodec()
    rng = np.random.default_rng(2026)
    n = 100_000
    bases = np.array([codec.base_id(m) for m in codec.message_names])
    profile = rng.random(n) < 0.6
    ids = np.where(profile, bases[rng.integers(0, len(bases), n)] + rng.integers(0, 16, n),
                   rng.integers(0, 0x800, n))
    lengths = np.where(rng.random(n) < 0.7, 8, rng.integers(0, 9, n))
    flags = rng.random(n)
    payload = rng.bytes(8 * n)
    frames = [
        can.Message(arbitration_id=int(ids[i]), data=payload[8 * i:8 * i + int(lengths[i])],
                    is_extended_id=bool(flags[i] < 0.03),
                    is_remote_frame=bool(0.03 <= flags[i] < 0.05),
                    is_error_frame=bool(0.05 <= flags[i] < 0.07), check=False)
        for i in range(n)
    ]
    receiver = ProfileReceiver(list(range(16)))
    decoded = rejected = crashes = 0
    t0 = time.perf_counter()
    for i, msg in enumerate(frames):
        try:
            frame = codec.decode(msg)
        except CodecError:
            rejected += 1
            continue
        except Exception:
            crashes += 1
            continue
        decoded += 1
        try:
            receiver.feed(frame, float(i))
        except Exception:
            crashes += 1
    dt = time.perf_counter() - t0
    return (
        "### Fuzzing the receive path\n\n"
        f"{n} random frames (60 % with profile ids, any length 0–8, 3 % extended, 2 % remote, "
        "2 % error frames) through `GliderCanCodec.decode` and the autopilot's "
        "`ProfileReceiver.feed`.\n\n"
        + table(["frames", "decoded", "rejected (CodecError)", "crashes", "frames/s"],
                [[n, decoded, rejected, crashes, f"{n / dt:,.0f}"]])
        + f"\n\nSaturated on receive (raw codes beyond the DBC range, clamped and counted): "
        f"{sum(codec.saturation_counts()['rx'].values())}.\n"
    )


def _bus_off_recovery() -> str:
    bus = "mem://bench_can_faults"
    adapter = AutopilotAdapter("autopilot", bus=bus, channel="bench_can_faults",
                               gliders=list(range(N_GLIDERS)), faults={"seed": 1})
    mock = MockAutopilot("mock", channel="bench_can_faults", gliders=list(range(N_GLIDERS)),
                         rate_hz=RATE_HZ)
    sim = Node("sim", bus=bus, diagnostics_period_s=0)
    pubs = [sim.create_publisher(GliderState, f"/glider/{g}/state") for g in range(N_GLIDERS)]
    arrivals: list[float] = []
    sim.create_subscription(GliderCmd, "/glider/0/cmd",
                            lambda _m: arrivals.append(time.monotonic()))
    stop = threading.Event()

    def feed() -> None:
        while not stop.wait(1.0 / RATE_HZ):
            for g, pub in enumerate(pubs):
                pub.publish(GliderState(stamp_ns=0, x=50.0 * g, y=0.0, z=1000.0, heading=0.0,
                                        bank=0.0, airspeed=10.0, vz=0.0, glider_id=g))

    feeder = threading.Thread(target=feed, daemon=True)
    recoveries, gaps = [], []
    for node in (sim, adapter, mock):
        node.start()
    feeder.start()
    try:
        time.sleep(1.0)
        for i in range(10):
            link = adapter.can.link
            assert link is not None and isinstance(link.bus, FaultInjectingBus)
            t0 = time.monotonic()
            link.bus.inject_bus_off(30.0)
            while adapter.stats().get("can_bus_off_recoveries", 0) < i + 1:
                time.sleep(0.001)
            recoveries.append(time.monotonic() - t0)
            time.sleep(0.3)
            after = [t for t in arrivals if t > t0]
            gaps.append(after[0] - t0 if after else float("nan"))
        stats = adapter.stats()
    finally:
        stop.set()
        feeder.join()
        for node in (mock, adapter, sim):
            node.stop()
    return (
        "### Bus-off recovery\n\n"
        f"Adapter and mock ({N_GLIDERS} gliders, states and commands at {RATE_HZ:g} Hz); 10 times "
        "a bus-off that never restarts by itself (`inject_bus_off(30)`), so the link must shut "
        "the bus down and re-open it. Recovery = injection to the first frame sent again; "
        "command gap = injection to the next `/glider/0/cmd`.\n\n"
        + table(["events", "recovery p50", "recovery max", "command gap p50", "command gap max",
                 "re-opens", "frames dropped while bus-off"],
                [[len(recoveries), fmt_s(median(recoveries)), fmt_s(max(recoveries)),
                  fmt_s(median(gaps)), fmt_s(max(gaps)), stats.get("can_reopens", 0),
                  stats.get("can_tx_dropped_bus_off", 0)]])
        + "\n"
    )


def _path_tracking() -> str:
    route = figure_eight_waypoints(center=(10.0, 10.0), half_length_m=7.0, n=24)
    run_s, rate = 20.0, 1.0
    scene = {"seed": 0, "state_rate_hz": RATE_HZ, "clock": {"mode": "realtime", "rate": rate},
             "vehicles": [{"id": 100, "commanded": True, "bank_max_rad": 0.5236,
                           "speed_min_mps": 1.0, "speed_max_mps": 8.0,
                           "path": {"kind": "points", "speed_mps": 3.0,
                                    "points": [[x, y, 2.0] for x, y in route]}}]}
    bus = "mem://bench_can_path"
    server = SimServer("server", bus=bus, scene=scene)
    adapter = AutopilotAdapter("autopilot", bus=bus, channel="bench_can_path",
                               gliders={100: 8})
    mock = MockAutopilot("mock", channel="bench_can_path", gliders=[8], controller="path",
                         waypoints=route, path_airspeed_mps=3.0, lookahead_m=3.0)
    probe = Node("probe", bus=bus, diagnostics_period_s=0)
    track: list[tuple[float, float]] = []
    probe.create_subscription(GliderState, "/glider/100/state",
                              lambda m: track.append((m.x, m.y)))
    nodes: list[Any] = [probe, server, adapter, mock]
    for node in nodes:
        node.start()
    time.sleep(run_s)
    for node in reversed(nodes):
        node.stop()
    p = np.array(track[len(track) // 2:])
    a, ab = route, np.roll(route, -1, axis=0) - route
    t = np.clip(((p[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    dist = np.min(np.linalg.norm(p[:, None, :] - (a + t[..., None] * ab), axis=-1), axis=1)
    return (
        "### Path following over CAN\n\n"
        "A commanded vehicle of the server (3 m/s, bank ≤ 30°) flown by the mock's pure-pursuit "
        "follower (10 Hz, look-ahead 3 m) around a 14 m × 7 m figure-eight (the demo's sonar "
        f"vehicle), {run_s:g} s; distance from the route over the second half.\n\n"
        + table(["samples", "distance p50", "distance p99", "distance max"],
                [[len(p), f"{np.median(dist):.2f} m", f"{np.percentile(dist, 99):.2f} m",
                  f"{dist.max():.2f} m"]])
        + "\n"
    )


def run(out_dir: Path) -> str:
    return "\n".join([_bus_load(out_dir), _bus_off_recovery(), _path_tracking(), _codec_cost(),
                      _fuzz()])
