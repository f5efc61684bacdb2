"""Bus benchmarks: state-path latency through the proxy vs raw pyzmq, recorder throughput, codec.

Latency: a 250 Hz publisher thread sends ``GliderState`` on ``/glider/0/state`` through a real
XSUB/XPUB proxy (loopback TCP) to a subscribing :class:`~hil_bridge.bus.node.Node` in the same
process; latency is the subscriber callback's ``time.monotonic_ns()`` minus the header's
``pub_ns``. A second thread meanwhile computes echo-like numpy work without pause (FFT
convolution of 64 Ki-sample signals), as the server's echo worker does. The baseline, measured in
the same run under the same load, is a raw pyzmq PUB → SUB pair (no proxy, no codec, no node
threads) sending the same bytes at the same rate; a third row sends them with raw pyzmq
through a proxy, to separate the topology's cost from the bridge's.

A node's receive cost: a feeder process runs a proxy and publishes what the 250 Hz demo's
server does (``/clock`` and 8 glider states at 250 Hz, 2,250 messages a second); a subscriber
:class:`~hil_bridge.bus.node.Node` with empty callbacks runs in a process of its own, and its
process's CPU time and context switches (all its threads, ``/proc/self/task/*/status``) per
message are measured over 8 s after 2 s of warm-up. Baseline: the same probe on the executor
before its fast mode (``git archive e35bd35 hil_bridge sim_core``), alternating with today's
code in the same run, 2 runs each (medians).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zmq

from bench._util import ROOT, fmt_s, git_tree, median, python_json, table, time_it
from hil_bridge.bus.codec import Envelope, decode, encode
from hil_bridge.bus.domain import claim_first_free
from hil_bridge.bus.messages import GliderState, Message, SonarEcho
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.recording.recorder import Recorder

TITLE = "Bus: state-path latency, recorder throughput, codec costs"

RATE_HZ = 250.0
RUN_S = 20.0

#: the executor before fast mode (hil_bridge/bus/executor.py): each message handed between its
#: two workers
RX_BASELINE_COMMIT = "e35bd35"
#: publishes the demo's 250 Hz state stream through a proxy of its own: argv domain number
_FEEDER = """
import sys, time
from hil_bridge.bus.domain import Domain
from hil_bridge.bus.messages import Clock, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.transport.zmq import parse_zmq_url
url = Domain(int(sys.argv[1])).bus_url
ends = parse_zmq_url(url)
with Proxy(ends.pub, ends.sub):
    node = Node("feeder", bus=url, diagnostics_period_s=0).start()
    clock = node.create_publisher(Clock, "/clock")
    pubs = [node.create_publisher(GliderState, f"/glider/{i}/state") for i in range(8)]
    print("ready", flush=True)
    t0, k = time.monotonic(), 0
    while True:
        time.sleep(max(0.0, t0 + k / 250.0 - time.monotonic()))
        clock.publish(Clock(stamp_ns=k * 4_000_000))
        for i, p in enumerate(pubs):
            p.publish(GliderState(stamp_ns=k * 4_000_000, x=float(i), y=2.0, z=40.0,
                                  heading=0.3, bank=0.2, airspeed=10.0, vz=-0.6, glider_id=i,
                                  step=k, roll=-0.2, pitch=0.05, yaw=0.3, qw=1.0, qx=0.0,
                                  qy=0.0, qz=0.0, roll_rate=0.0, pitch_rate=0.0, yaw_rate=0.2))
        k += 1
"""
#: a Node taking the feeder's 9 topics, against the hil_bridge in argv[1]: CPU and context
#: switches of this process per message
_RX_PROBE = """
import json, os, sys, time
sys.path.insert(0, sys.argv[1])
from hil_bridge.bus.messages import Clock, GliderState
from hil_bridge.bus.node import Node
count = [0]
def cb(msg):
    count[0] += 1
def switches():
    total = 0
    for t in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{t}/status") as f:
                total += sum(int(l.split(":")[1]) for l in f if "ctxt_switches" in l)
        except OSError:
            pass
    return total
node = Node("probe", bus=sys.argv[2], diagnostics_period_s=0)
node.create_subscription(Clock, "/clock", cb)
for i in range(8):
    node.create_subscription(GliderState, f"/glider/{i}/state", cb)
node.start()
time.sleep(2.0)
t, n, x, w = os.times(), count[0], switches(), time.monotonic()
time.sleep(8.0)
t2, n2, x2, w2 = os.times(), count[0], switches(), time.monotonic()
node.stop()
msgs = max(n2 - n, 1)
print(json.dumps({"rate": msgs / (w2 - w),
                  "cpu_us": 1e6 * (t2.user + t2.system - t.user - t.system) / msgs,
                  "ctx": (x2 - x) / msgs}))
"""


def _state(i: int) -> GliderState:
    return GliderState(stamp_ns=i * 4_000_000, x=float(i), y=2.0, z=150.0, heading=0.3,
                       bank=0.1, airspeed=9.5, vz=-0.6, glider_id=0, step=i)


def _echo(n: int = 4096) -> SonarEcho:
    samples = np.sin(np.arange(2 * n, dtype=np.float32)).reshape(2, n)
    return SonarEcho(stamp_ns=0, ping_seq=1, fs=400e3, samples=samples, leaves_in_beam=321,
                     fidelity="fast")


class _Load:
    """A thread doing echo-like numpy work until stopped; counts completed 'echoes'."""

    def __init__(self) -> None:
        self.stop = threading.Event()
        self.count = 0
        self.thread = threading.Thread(target=self._run, name="bench-load", daemon=True)

    def _run(self) -> None:
        rng = np.random.default_rng(0)
        x = rng.standard_normal(1 << 16)
        kernel = np.fft.rfft(np.hanning(257), n=1 << 16)
        while not self.stop.is_set():
            y = np.fft.irfft(np.fft.rfft(x) * kernel, n=1 << 16)
            x = 0.5 * x + 0.5 * y / (np.abs(y).max() + 1e-12)
            self.count += 1

    def __enter__(self) -> _Load:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()


def _paced(n: int, send: Callable[[int], None]) -> None:
    period = 1.0 / RATE_HZ
    wait = threading.Event()
    t_next = time.monotonic()
    for i in range(n):
        send(i)
        t_next += period
        delay = t_next - time.monotonic()
        if delay > 0:
            wait.wait(delay)


def _summary(lat_ns: list[int], arrivals_ns: list[int], n: int) -> dict[str, float]:
    if not lat_ns:
        raise RuntimeError("no message arrived")
    lat = np.asarray(lat_ns, dtype=np.float64) / 1e6
    gaps = np.diff(np.asarray(arrivals_ns, dtype=np.float64)) / 1e6
    return {
        "received": float(len(lat_ns)),
        "sent": float(n),
        "p50_ms": float(np.percentile(lat, 50)),
        "p99_ms": float(np.percentile(lat, 99)),
        "max_ms": float(lat.max()),
        "max_gap_ms": float(gaps.max()) if gaps.size else float("nan"),
        "gaps_over_20ms": float(np.count_nonzero(gaps > 20.0)),
    }


def _raw_zmq(n: int, proxy: Proxy | None = None) -> tuple[dict[str, float], list[int]]:
    """Raw pyzmq PUB → SUB on loopback (directly, or through ``proxy``), same frames and rate;
    latency from a send timestamp carried in the header frame."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    pub = ctx.socket(zmq.PUB)
    sub = ctx.socket(zmq.SUB)
    for s in (pub, sub):
        s.linger = 0
    if proxy is None:
        port = pub.bind_to_random_port("tcp://127.0.0.1")
        sub.connect(f"tcp://127.0.0.1:{port}")
    else:
        pub.connect(proxy.pub_endpoint)
        sub.connect(proxy.sub_endpoint)
    sub.subscribe(b"/glider/0/state\0")
    # raw pyzmq has no subscription handshake: probe until a message gets through
    while True:
        pub.send_multipart([b"/glider/0/state\0", b"probe", b""])
        if sub.poll(10):
            sub.recv_multipart()
            break
    while sub.poll(50):
        sub.recv_multipart()
    frames = encode("/glider/0/state", _state(0), seq=0, pub_ns=0)
    lat: list[int] = []
    arrivals: list[int] = []

    def receive() -> None:
        while len(lat) < n and sub.poll(2000):
            msg = sub.recv_multipart()
            now = time.monotonic_ns()
            lat.append(now - int.from_bytes(msg[1][:8], "little"))
            arrivals.append(now)

    rx = threading.Thread(target=receive)
    rx.start()

    def send(i: int) -> None:
        pub.send_multipart(
            [frames[0], time.monotonic_ns().to_bytes(8, "little") + frames[1], frames[2]]
        )

    _paced(n, send)
    rx.join()
    pub.close()
    sub.close()
    return _summary(lat, arrivals, n), lat


def _bridge(n: int) -> tuple[dict[str, float], list[int]]:
    """Node → proxy → Node, 250 Hz GliderState; latency from header pub_ns to the callback."""
    lat: list[int] = []
    arrivals: list[int] = []
    done = threading.Event()

    def on_state(env: Envelope) -> None:
        now = time.monotonic_ns()
        lat.append(now - env.header.pub_ns)
        arrivals.append(now)
        if len(lat) >= n:
            done.set()

    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy, \
            Node("bench_sim", bus=proxy.url, diagnostics_period_s=0) as sim, \
            Node("bench_ap", bus=proxy.url, diagnostics_period_s=0) as ap:
        sim.start()
        ap.start()
        pub = sim.create_publisher(GliderState, "/glider/0/state")
        ap.create_subscription(GliderState, "/glider/0/state", on_state, envelope=True)
        if not pub.wait_for_subscribers(10.0):
            raise RuntimeError("subscriber never reached the publisher through the proxy")
        def send(i: int) -> None:
            pub.publish(_state(i))

        _paced(n, send)
        done.wait(5.0)
        dropped = ap.stats()["dropped"]
    out = _summary(lat, arrivals, n)
    out["dropped"] = float(dropped)
    return out, lat


def _recorder_throughput(
    msg_type: type[Message], msg_factory: Callable[[int], Message], n: int
) -> tuple[float, float]:
    """Messages/s and MB/s a Recorder writes from an in-process bus (the publisher outpaces it:
    the mem queue is deep enough to hold the whole burst, so nothing is dropped)."""
    bus = f"mem://bench_rec_{n}_{id(msg_factory)}?depth={n + 10}"
    with tempfile.TemporaryDirectory() as tmp:
        rec = Recorder(Path(tmp) / "bench.mcap", bus=bus)
        rec.start()
        try:
            with Node("bench_pub", bus=bus, diagnostics_period_s=0) as node:
                pub = node.create_publisher(msg_type, "/bench")
                pub.wait_for_subscribers(10.0)
                t0 = time.perf_counter()
                for i in range(n):
                    pub.publish(msg_factory(i))
                rec.wait_for(n, 120.0)
                dt = time.perf_counter() - t0
        finally:
            rec.stop()
        nbytes = rec.stats()["bytes"]
    return n / dt, nbytes / dt / 1e6


def _plot(out_dir: Path, raw_ns: list[int], bridge_ns: list[int]) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    bins = [float(b) for b in np.logspace(-2, 1.5, 80)]
    ax.hist(np.asarray(raw_ns) / 1e6, bins=bins, alpha=0.6, label="raw pyzmq PUB→SUB")
    ax.hist(np.asarray(bridge_ns) / 1e6, bins=bins, alpha=0.6, label="echoloop node→proxy→node")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("one-way latency (ms)")
    ax.set_ylabel("messages")
    ax.set_title(f"250 Hz GliderState, {RUN_S:.0f} s each, numpy load thread running")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out_dir / "bus_latency.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path.name


def _codec_row(label: str, msg: Message, frames: list[bytes]) -> list[str]:
    t_enc = median(time_it(lambda: encode("/t", msg, seq=1, pub_ns=2), repeat=2000))
    t_dec = median(time_it(lambda: decode(frames), repeat=2000))
    return [label, f"{sum(len(f) for f in frames)} B", fmt_s(t_enc), fmt_s(t_dec)]


def _receive_cost() -> str:
    """The node receive-cost table (module docstring)."""
    runs: dict[str, list[dict[str, float]]] = {"today": [], "before": []}
    with tempfile.TemporaryDirectory(prefix="echoloop-bench-") as tmp, \
            claim_first_free() as (dom, _):
        trees = {"today": str(ROOT)}
        if git_tree(RX_BASELINE_COMMIT, Path(tmp), ("hil_bridge", "sim_core")):
            trees["before"] = tmp
        feeder = subprocess.Popen([sys.executable, "-c", _FEEDER, str(dom.number)], cwd=ROOT,
                                  stdout=subprocess.PIPE, text=True)
        try:
            assert feeder.stdout is not None
            feeder.stdout.readline()
            for _ in range(2):
                for key, tree in trees.items():
                    runs[key].append(python_json(_RX_PROBE, tree, dom.bus_url))
        finally:
            feeder.kill()
            feeder.wait()

    def cells(key: str) -> list[str]:
        if not runs[key]:
            return ["—", "—", "—"]
        return [f"{median([r[k] for r in runs[key]]):{f}}"
                for k, f in (("rate", ".0f"), ("cpu_us", ".1f"), ("ctx", ".2f"))]

    return table(["subscriber", "messages/s", "CPU µs per message", "context switches per message"],
                 [[f"executor of {RX_BASELINE_COMMIT} (a hand-off per message)", *cells("before")],
                  ["today's executor (fast mode from 200 messages/s)", *cells("today")]])


def run(out_dir: Path) -> str:
    rx_cost = _receive_cost()
    n = int(RUN_S * RATE_HZ)
    state, echo = _state(7), _echo()
    state_frames = encode("/glider/0/state", state, seq=1, pub_ns=2)
    echo_frames = encode("/sonar/0/echo", echo, seq=1, pub_ns=2)
    codec_rows = [
        _codec_row("GliderState", state, state_frames),
        _codec_row("SonarEcho 2×4096 f32", echo, echo_frames),
    ]

    with _Load() as load:
        raw, raw_ns = _raw_zmq(n)
        with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy:
            via, _ = _raw_zmq(n, proxy)
        bridge, bridge_ns = _bridge(n)
        echoes = load.count

    def row(name: str, r: dict[str, float]) -> list[str]:
        return [name, f"{int(r['received'])}/{int(r['sent'])}", f"{r['p50_ms']:.3f}",
                f"{r['p99_ms']:.3f}", f"{r['max_ms']:.2f}", f"{r['max_gap_ms']:.2f}",
                f"{int(r['gaps_over_20ms'])}"]

    lat_rows = [
        row("raw pyzmq PUB→SUB (baseline)", raw),
        row("raw pyzmq PUB→proxy→SUB", via),
        row("echoloop Node→proxy→Node", bridge),
    ]
    added_p50 = bridge["p50_ms"] - raw["p50_ms"]
    added_p99 = bridge["p99_ms"] - raw["p99_ms"]
    figure = _plot(out_dir, raw_ns, bridge_ns)

    rec_state = _recorder_throughput(GliderState, _state, 20_000)
    echo_msg = _echo()
    rec_echo = _recorder_throughput(SonarEcho, lambda i: echo_msg, 2_000)

    lines = [
        __doc__.split("\n\n", 1)[1].strip() if __doc__ else "",
        "",
        f"### State path at {RATE_HZ:.0f} Hz for {RUN_S:.0f} s each "
        f"(load thread finished {echoes} 64 Ki-sample FFT convolutions meanwhile)",
        "",
        table(["path", "received", "p50 ms", "p99 ms", "max ms", "max gap ms", "gaps > 20 ms"],
              lat_rows),
        "",
        f"Bridge-added latency (bridge − raw, same run): p50 **{added_p50:.3f} ms** "
        f"(goal ≤ 0.2), p99 **{added_p99:+.3f} ms** (goal ≤ 2; tails on a shared machine are "
        "dominated by other processes, so this difference can even be negative); bridge max "
        "inter-message gap "
        f"**{bridge['max_gap_ms']:.2f} ms** (goal ≤ 20; nominal period 4 ms) with "
        f"{int(bridge['gaps_over_20ms'])} gaps over 20 ms, against "
        f"{int(raw['gaps_over_20ms'])} for raw pyzmq in the same run (max "
        f"{raw['max_gap_ms']:.2f} ms): a stall of the whole process on this shared machine hits "
        "whichever path is running, so compare the paths, not one maximum; subscriber "
        f"counted {int(bridge['dropped'])} dropped. Of the added p50, the proxy hop that the "
        f"spec's topology requires accounts for {via['p50_ms'] - raw['p50_ms']:.3f} ms (raw "
        "pyzmq through the same kind of proxy); the rest is the bridge's own Python path "
        "(codec, locks, GIL hand-overs with the load thread).",
        "",
        "### A node's receive cost: /clock and 8 glider states at 250 Hz",
        "",
        rx_cost,
        "",
        "### Recorder throughput (in-process bus → MCAP, zstd, 64 KiB chunks)",
        "",
        table(["message", "msgs/s", "MB/s payload"],
              [["GliderState", f"{rec_state[0]:,.0f}", f"{rec_state[1]:.2f}"],
               ["SonarEcho 2×4096 f32", f"{rec_echo[0]:,.0f}", f"{rec_echo[1]:.1f}"]]),
        "",
        "### Codec (median per call, 2000 calls)",
        "",
        table(["message", "wire size", "encode", "decode"], codec_rows),
    ]
    lines += ["", f"![latency histogram](docs/figures/bench/{figure})"]
    return "\n".join(lines)
