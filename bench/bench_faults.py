"""Faults: the closed loop under a flood of malformed messages; recovering a killed recording.

1. **Flood isolation.** The demo graph (``launch/demo.yaml``: server with 8 soaring gliders and
   the sonar vehicle, mock sonar head + serial adapter, CAN adapter, mock autopilots) runs on a
   free loopback ``tcp://`` bus twice: quiet, and with ``python -m hil_bridge.tools.flood`` (a
   separate process) injecting FLOOD_RATE malformed messages/s on ``/glider/0/state`` for FLOOD_S
   seconds after a WARMUP_S warm-up. Measured: the injected rate; the state latency (server
   ``pub_ns`` → the CAN adapter's state callback) over the adapter's last 10,000 states; the
   malformed messages the adapter dropped and counted per second; hold/failsafe entries and
   failsafe commands of the CAN adapter (goal: 0); the sonar head's ping outcomes.
2. **Recovery.** A recorder in a child process records incompressible echoes and states until
   it is killed with SIGKILL; ``hil_bridge.recording.bag_writer.recover`` turns its unfinished
   ``.part`` file into a finished one. Measured: recover speed (MB/s of input, median of 3)
   and the kept fraction (messages recovered / messages the recorder had received when it was
   killed).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from bench._util import median, table
from hil_bridge.launch.runner import LaunchSpec, load
from hil_bridge.launch.runner import run as run_launch
from hil_bridge.recording.bag_writer import recover

TITLE = "Faults: flood isolation, recovering a killed recording"

ROOT = Path(__file__).resolve().parent.parent
FLOOD_RATE = 25_000
FLOOD_S = 20.0
WARMUP_S = 4.0
FLOODED = "/glider/0/state"
VEHICLES = (*range(8), 100)


def _free_port_pair() -> int:
    """A port p with p and p + 1 free on loopback (the bus needs both)."""
    for _ in range(100):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
            with socket.socket() as b:
                try:
                    b.bind(("127.0.0.1", port + 1))
                except OSError:
                    continue
                return int(port)
    raise OSError("no free pair of loopback ports")


def _demo(bus: str, tmp: Path) -> LaunchSpec:
    link = str(tmp / "sonar0")
    return load(ROOT / "launch" / "demo.yaml", params_overrides={
        "sonar_head_mock": {"link": link}, "sonar_head": {"port": link},
        "autopilot": {"channel": f"bench_faults_{os.getpid()}"},
        "mock_autopilot_swarm": {"channel": f"bench_faults_{os.getpid()}"},
        "mock_autopilot_sonar": {"channel": f"bench_faults_{os.getpid()}"},
    })


def _run(flood: bool, tmp: Path) -> dict[str, Any]:
    port = _free_port_pair()
    bus = f"tcp://127.0.0.1:{port}"
    spec = _demo(bus, tmp)
    started = threading.Event()
    stop = threading.Event()
    out: dict[str, Any] = {}

    def launch() -> None:
        out["summary"] = run_launch(spec, bus=bus, stop_event=stop, handle_signals=False,
                                    on_started=lambda _s: started.set())

    thread = threading.Thread(target=launch, name="bench-launch")
    thread.start()
    try:
        if not started.wait(60):
            raise RuntimeError("the demo graph did not start")
        stop.wait(WARMUP_S)
        if flood:
            proc = subprocess.run(
                [sys.executable, "-m", "hil_bridge.tools.flood", "--bus", bus, "--topic", FLOODED,
                 "--rate", str(FLOOD_RATE), "--duration", str(FLOOD_S)],
                capture_output=True, text=True, check=True, cwd=ROOT, timeout=FLOOD_S + 60)
            sent, secs = proc.stdout.split()[1], proc.stdout.split(" in ")[1].split()[0]
            out["sent"], out["flood_s"] = int(sent), float(secs)
        else:
            stop.wait(FLOOD_S)
            out["sent"], out["flood_s"] = 0, FLOOD_S
    finally:
        stop.set()
        thread.join()
    return out


def _flood_section() -> str:
    rows = []
    with tempfile.TemporaryDirectory() as d:
        results = {name: _run(name == "flooded", Path(d)) for name in ("quiet", "flooded")}
    for name, res in results.items():
        s = res["summary"]
        ad = s.nodes["autopilot"]
        head = s.nodes["sonar_head_mock"]
        by = ad.get("state_latency_ms_by_glider", {})
        others = [by[g] for g in by if g != "0" and by[g].get("n")]
        flooded = by.get("0", {})
        topic = ad["topics"].get(FLOODED, {})
        dropped = topic.get("decode_errors", 0)
        rows.append([
            name, f"{res['sent'] / res['flood_s']:.0f}" if res["sent"] else "0",
            f"{max(o['p50'] for o in others):.2f} / {max(o['p99'] for o in others):.2f}",
            f"{flooded.get('n', 0)}: {flooded.get('p50', float('nan')):.2f} / "
            f"{flooded.get('p99', float('nan')):.2f}",
            f"{topic.get('stale', 0)} / {topic.get('queue_resets', 0)}",
            f"{dropped / res['flood_s']:.0f}",
            f"{ad.get('hold_entries', 0)} / {ad.get('failsafe_entries', 0)} / "
            f"{ad.get('cmd_failsafe_published', 0)}",
            f"{head['pings_sent']} = {head['echoes_complete']} + {head['echoes_incomplete']} + "
            f"{head['echo_timeouts']} + {head['pings_in_flight']}",
            f"{s.monitor['state_latency_ms']['p50']:.2f} / "
            f"{s.monitor['state_latency_ms']['p99']:.2f} ({s.monitor.get('throttled_s', 0):.1f})",
            f"{s.exit_status}",
        ])
    return (
        f"Demo graph on loopback `tcp://`, {WARMUP_S:.0f} s warm-up, then {FLOOD_S:.0f} s quiet "
        f"or under `python -m hil_bridge.tools.flood --rate {FLOOD_RATE}` (malformed messages "
        f"of every kind on `{FLOODED}`, a separate process); the run ends with the flood. State "
        "latency = the CAN adapter's state callback time − the server's `pub_ns` (same host), "
        "ms, over its last 10,000 state callbacks (9 vehicles × 50 Hz: the last 22 s, 20 s of "
        "them flooded), for the 8 vehicles whose topic is not flooded (the worst of them) and "
        "for glider 0. Stale = states of glider 0 older than the adapter's `state_max_age_s` "
        "(0.1 s of sim time against `/clock`), dropped before the autopilot sees them, each "
        "dropping the queue behind it (at most one reset per 0.1 s). Dropped = malformed "
        "messages the adapter counted as decode errors on the flooded topic per second of "
        "flood (the rest were dropped unread with the queue resets). Hold / failsafe: the "
        "adapter's command supervision entries and failsafe "
        "commands published (goal: 0). Monitor: the launch run summary's bus monitor (one "
        "subscription to every topic, whole run; capped at 5 % of a core while garbage "
        "outnumbers good messages, so its figures under the flood are partial).\n\n"
        + table(["run", "injected msg/s", "other 8 vehicles: worst p50 / p99 ms",
                 "flooded glider 0: n: p50 / p99 ms", "glider 0 stale / queue resets",
                 "adapter dropped msg/s", "hold / failsafe entries / failsafe cmds",
                 "pings = complete + incomplete + timeouts + in flight",
                 "monitor p50 / p99 ms (throttled s)", "exit"], rows)
    )


_CHILD = textwrap.dedent("""
    import sys, threading
    import numpy as np
    from hil_bridge.bus.messages import GliderState, SonarEcho
    from hil_bridge.bus.node import Node
    from hil_bridge.recording.recorder import Recorder
    bus = "mem://bench_kill?depth=100000"
    rec = Recorder(sys.argv[1], bus=bus, diagnostics_period_s=0)
    rec.start()
    node = Node("src", bus=bus, diagnostics_period_s=0)
    echoes = node.create_publisher(SonarEcho, "/sonar/0/echo")
    states = node.create_publisher(GliderState, "/glider/0/state")
    rng = np.random.default_rng(0)
    noise = [rng.standard_normal(8192).astype(np.float32) for _ in range(16)]
    i = 0
    tick = threading.Event()
    while True:
        echoes.publish(SonarEcho(stamp_ns=i, ping_seq=i, fs=4e5, samples=noise[i % 16],
                                 leaves_in_beam=i, fidelity="fast"))
        for k in range(10):
            states.publish(GliderState(stamp_ns=i * 10 + k, x=float(i), y=0.0, z=100.0,
                                       heading=0.1, bank=0.0, airspeed=10.0, vz=0.0))
        i += 1
        if i % 50 == 0:
            print(rec.stats()["messages"], flush=True)
            tick.wait(0.01)
""")


def _recover_section() -> str:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "killed.mcap"
        proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(path)], cwd=ROOT, text=True,
                                stdout=subprocess.PIPE)
        received = 0
        t_end = time.monotonic() + 8.0
        assert proc.stdout is not None
        try:
            while time.monotonic() < t_end:
                line = proc.stdout.readline()
                if not line:
                    break
                received = int(line)
        finally:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
        (part,) = Path(d).glob(".killed.*.part.mcap")
        size = part.stat().st_size
        times = []
        kept = 0
        for k in range(3):
            out = Path(d) / f"fixed{k}.mcap"
            t0 = time.perf_counter()
            report = recover(part, out)
            times.append(time.perf_counter() - t0)
            kept = report.messages
        with open(Path(d) / "fixed0.mcap", "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            standard = summary.statistics.message_count if summary and summary.statistics else -1
    t = median(times)
    return (
        "A recorder (64 KiB zstd chunks, flushed every second) in a child process records "
        "32 KiB noise echoes and states (10 per echo) for 8 s and is killed with SIGKILL; "
        "`recover` writes a finished copy of its `.part` file. Received = the recorder's own "
        "count at its last report before the kill (reports every 50 echoes, so the kept "
        "fraction can exceed 1 by what it received after that report).\n\n"
        + table(["input MB", "recover s (median of 3)", "MB/s", "received before kill",
                 "kept", "kept fraction", "standard reader's count"],
                [[f"{size / 1e6:.1f}", f"{t:.2f}", f"{size / 1e6 / t:.0f}", received, kept,
                  f"{kept / received:.3f}" if received else "-", standard]])
    )


def run(out_dir: Path) -> str:
    return "\n\n".join(["### Flood isolation", _flood_section(),
                        "### Recovering a killed recording", _recover_section()])


if __name__ == "__main__":
    print(run(Path(tempfile.mkdtemp())))
