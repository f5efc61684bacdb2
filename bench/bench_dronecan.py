"""DroneCAN: bus load at 1 Mbit/s, the node's echo -> Measurement latency, its hot path.

1. **The launch as users run it, against a flight controller.** ``launch/dronecan_glider.yaml``
   in processes (the server in real time at 100 Hz, a two-eared sonar pinged at 20 Hz, the
   :class:`~drivers.dronecan.node.DroneCanNode` with air data at 50 Hz and GNSS at 10 Hz) on
   ``mcast:N``, and the flight controller's stand-in (:mod:`drivers.mocks.dronecan_peer`: the
   ``dronecan`` package's own node and allocator, a process of its own) sending a 4-servo
   ``actuator.ArrayCommand`` at 50 Hz. A third socket on the bus records every frame for
   ``WINDOW_S``: frames and transfers a second by data type, each frame's exact length on the
   wire (CAN 2.0B extended, its CRC-15 and bit stuffing computed: :mod:`drivers.can.busload`)
   and the worst case (every frame stuffed to the bound), as a share of 1 Mbit/s. The node's
   ``echo_to_can_us`` (an echo's arrival in the node to its last ``Measurement`` written to
   the bus) from each of ``REPEAT`` launches.
2. **The hot path in a loop** (the floor of that latency on this machine): the range rule on
   a recorded-shape echo of two ears, filling two ``Measurement`` objects, and broadcasting
   them through a ``dronecan`` node onto a driver that discards frames.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import fmt_s, median, table, time_it
from drivers.can.busload import frame_bits, worst_case_bits
from hil_bridge.bus.domain import Domain, claim_first_free

TITLE = "DroneCAN: bus load at 1 Mbit/s, echo -> Measurement latency"

ROOT = Path(__file__).resolve().parent.parent
LAUNCH = ROOT / "launch" / "dronecan_glider.yaml"
BITRATE = 1_000_000
WINDOW_S = 20.0
REPEAT = 2
COLD_CALLS = 100


def _type_name(frame_id: int) -> tuple[str, bool]:
    """(DSDL name, is a service) of a DroneCAN frame id (29 bits)."""
    import dronecan

    service = bool(frame_id & 0x80)
    if service:
        dtid, kind = (frame_id >> 16) & 0xFF, 0
    elif frame_id & 0x7F == 0:  # anonymous: the low 2 bits of the type id only
        dtid, kind = (frame_id >> 8) & 0x3, 1
    else:
        dtid, kind = (frame_id >> 8) & 0xFFFF, 1
    t = dronecan.DATATYPES.get((dtid, kind))
    return (t.full_name if t is not None else f"unknown {dtid}"), service


class _Sniffer:
    """Every frame on ``mcast:bus`` (time, id, data), from a socket of its own."""

    def __init__(self, bus: int) -> None:
        from drivers.dronecan.mcast import McastDriver

        self.driver = McastDriver(bus)
        self.frames: list[tuple[float, int, bytes]] = []
        self.recording = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sniffer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            f = self.driver.receive(0.05)
            if f is not None and self.recording:
                self.frames.append((time.monotonic(), f.id, bytes(f.data)))

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.driver.close()


def _launch_once(domain: Domain) -> tuple[list[tuple[float, int, bytes]], float, dict[str, Any]]:
    """One launch with the peer: (the frames of the window, its length in s, the node's
    stats)."""
    n = domain.number
    assert n is not None
    sniffer = _Sniffer(n)
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(LAUNCH), "--domain", str(n),
         "--duration", "600", "--json"], cwd=ROOT, text=True, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    peer = None
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "echoloop launch: running" in line:
                break
        else:
            raise RuntimeError(f"bench dronecan: the launch never ran: {proc.communicate()[1]}")
        peer = subprocess.Popen(
            [sys.executable, "-m", "drivers.mocks.dronecan_peer", "--bus", str(n), "--seconds",
             str(WINDOW_S + 8.0), "--servo-hz", "50"], cwd=ROOT, text=True,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        time.sleep(5.0)  # allocation, the first pings, the peer's servo loop running
        sniffer.recording = True
        t0 = time.monotonic()
        time.sleep(WINDOW_S)
        sniffer.recording = False
        span = time.monotonic() - t0
        peer.communicate(timeout=60)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        sniffer.close()
        for p in (peer, proc):
            if p is not None and p.poll() is None:
                p.kill()
                p.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"bench dronecan: the launch failed: {err[-2000:]}")
    return sniffer.frames, span, json.loads(out)["nodes"]["dronecan"]


def _load_table(frames: list[tuple[float, int, bytes]], span: float) -> tuple[str, float, float]:
    count: Counter[str] = Counter()
    transfers: Counter[str] = Counter()
    bits: Counter[str] = Counter()
    worst: Counter[str] = Counter()
    payload: Counter[str] = Counter()
    for _, fid, data in frames:
        name, service = _type_name(fid)
        if service:
            name += " (service)"
        count[name] += 1
        bits[name] += frame_bits(fid, data, extended=True)
        worst[name] += worst_case_bits(len(data), extended=True)
        payload[name] += len(data)
        if data and data[-1] & 0x80:  # the tail byte's start-of-transfer bit
            transfers[name] += 1
    rows = []
    for name, _ in sorted(bits.items(), key=lambda kv: -kv[1]):
        rows.append([f"`{name}`", f"{transfers[name] / span:.1f}", f"{count[name] / span:.1f}",
                     f"{payload[name] / count[name]:.1f}", f"{bits[name] / count[name]:.1f}",
                     f"{100 * bits[name] / span / BITRATE:.2f} %",
                     f"{100 * worst[name] / span / BITRATE:.2f} %"])
    typ = 100 * sum(bits.values()) / span / BITRATE
    bound = 100 * sum(worst.values()) / span / BITRATE
    rows.append(["**total**", f"**{sum(transfers.values()) / span:.0f}**",
                 f"**{sum(count.values()) / span:.0f}**", "", "", f"**{typ:.2f} %**",
                 f"**{bound:.2f} %**"])
    return table(["data type", "transfers/s", "frames/s", "bytes/frame", "bits/frame (stuffed)",
                  "load", "load, worst-case stuffing"], rows), typ, bound


def _bus_section() -> str:
    runs = []
    with claim_first_free(Domain(46)) as (domain, _):
        for _ in range(REPEAT):
            runs.append(_launch_once(domain))
    frames, span, _ = runs[0]
    load, typ, bound = _load_table(frames, span)
    lat_rows = []
    for k, (_, _, dc) in enumerate(runs):
        lat = dc["echo_to_can_us"]
        cpu = dc["echo_cpu_us"]
        lat_rows.append([f"launch {k + 1}", lat["n"], f"{lat['p50']:.0f}", f"{lat['p90']:.0f}",
                         f"{lat['p99']:.0f}", f"{lat['max']:.0f}", f"{cpu['p50']:.0f}",
                         f"{cpu['p99']:.0f}", dc["measurements_sent"], dc["transfers_bad"]])
    p99 = median([dc["echo_to_can_us"]["p99"] for _, _, dc in runs])
    p50 = median([dc["echo_to_can_us"]["p50"] for _, _, dc in runs])
    return (
        f"### Bus load: `launch/dronecan_glider.yaml` and a flight controller's 50 Hz "
        f"`ArrayCommand`, {span:.1f} s of frames on `mcast:N`\n\n"
        + load
        + f"\n\nThe bus at 1 Mbit/s carries **{typ:.1f} %** (every frame's exact length), "
        f"**{bound:.1f} %** if every frame were stuffed to the bound: goal (issue 42) ≤ 30 % "
        f"{'✓' if bound <= 30 else '✗'}. Two ranges at 20 Hz (one `Measurement` per ear of "
        "the sonar), air data at 50 Hz (`RawAirData`, `StaticPressure`, `StaticTemperature`), "
        "`Fix2` at 10 Hz, the peer's `ArrayCommand` (4 servos, 3 frames) at 50 Hz and each "
        "node's `NodeStatus` at 1 Hz (allocation and `GetNodeInfo` came before the window)."
        "\n\n"
        f"### Echo → `Measurement` on the bus, added by the node ({REPEAT} launches of "
        f"{WINDOW_S + 13:.0f} s or so)\n\n"
        + table(["run", "echoes", "µs p50", "p90", "p99", "max", "CPU µs p50", "CPU p99",
                 "Measurements sent", "transfers dropped"], lat_rows)
        + f"\n\nMedian p50 {p50:.0f} µs, p99 **{p99:.0f} µs**: goal (issue 42) ≤ 1000 µs p99 "
        f"{'✓' if p99 <= 1000 else '✗'}. The node's time from an echo's arrival in its bus "
        "callback to its last frame handed to the socket (`echo_to_can_us`), and the CPU "
        "time its thread spent meanwhile (`echo_cpu_us`; the rest it waited for a core), in "
        "a launch whose server computes the echoes and steps the glider, and whose flight "
        f"controller stand-in runs, on the same {os.cpu_count()} cores; the launch runs the "
        "server and the node under `SCHED_FIFO` where the OS allows it (`realtime:`)."
    )


def _hot_section() -> str:
    import dronecan

    from drivers.dronecan.messages import measurement
    from sim_core.sensors import RangeRule, echo_ranges
    from tests.drivers.mavlink.test_ranges import leaf_echo

    class _Null:
        def send(self, *_: Any, **__: Any) -> None:
            return None

        def receive(self, timeout: float | None = None) -> None:
            return None

        def close(self) -> None:
            return None

    echo = leaf_echo(4.0)
    samples = np.vstack([echo.samples[0], echo.samples[-1]]).astype(np.float32)  # as published
    rule = RangeRule()
    node = dronecan.node.Node(_Null(), node_id=42)
    axis = np.array([0.0, 0.0, -1.0])
    msgs = [measurement(0, 1 + k, 4.0, axis, min_m=0.2, max_m=10.0, fov_rad=0.7)
            for k in range(2)]

    def rule_once() -> None:
        echo_ranges(samples, float(echo.fs), rule)

    def fill() -> None:
        for k, m in enumerate(msgs):
            measurement(123, 1 + k, 4.0, axis, min_m=0.2, max_m=10.0, fov_rad=0.7, into=m)

    def send() -> None:
        for m in msgs:
            node.broadcast(m)

    def whole() -> None:
        rule_once()
        fill()
        send()

    rows = []
    total = 0.0
    for label, fn in (("the range rule, two ears", rule_once), ("two Measurements filled", fill),
                      ("two Measurements broadcast (3 frames each)", send)):
        t = median(time_it(fn, repeat=201))
        total += t
        rows.append([label, fmt_s(t)])
    rows.append(["**sum**, back to back", f"**{fmt_s(total)}**"])
    cold = []
    for _ in range(COLD_CALLS):
        time.sleep(0.05)
        t0 = time.perf_counter()
        whole()
        cold.append(time.perf_counter() - t0)
    rows.append(["the whole, one echo every 50 ms (the pinger's period)",
                 f"{fmt_s(median(cold))} (p99 {fmt_s(float(np.percentile(cold, 99)))})"])
    return (
        f"### The hot path in a loop: {samples.shape[1]} single-precision samples an ear at "
        f"{float(echo.fs) / 1e3:.0f} kHz (medians of 201 calls; {COLD_CALLS} one every 50 ms)\n\n"
        + table(["stage", "per echo"], rows)
        + "\n\nWhat an echo costs the node with nothing else running: back to back, and as "
        "the node meets echoes, after 50 ms of sleep (the same work on a core that was idle "
        "runs slower on this machine: its caches cold, its virtual CPU woken). The launch's "
        "figures above add what the other work on the cores takes."
    )


def run(out_dir: Path) -> str:
    del out_dir  # no figures
    return _bus_section() + "\n\n" + _hot_section()
