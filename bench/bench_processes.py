"""The process model's cost: the demo with every node a process against every node a thread.

``echoloop launch launch/demo.yaml --duration RUN_S --json`` runs as a child of this benchmark in a
free domain (its own loopback ZeroMQ bus), once with each node in its own process (the default) and
once with ``--threads``, interleaved ``REPEAT`` times. Measured per run: start-up (command start ->
every node running, the "running" line), stop (the end of the duration -> the command's exit), the
resident memory of each process halfway through the run (``/proc/PID/status`` VmRSS: per node host,
and the launcher), the CPU seconds of the command and all its processes (``RUSAGE_CHILDREN``) per
sim second, and what the loop delivered: sim seconds, echoes, ping -> echo and state latency
percentiles from the launch's monitor (in the launcher: ``SCHED_FIFO`` 1, below the real-time
nodes, when the launch has some, as the demo has; else nice +5, and its receive times include its
wait for a core), the state latency p99 at the CAN adapter ``autopilot`` (its ``state_latency_ms``:
bus publish -> its state callback, the consumer the states are for), and the largest gap between
consecutive publishes of a glider's state (the monitor's ``state_gap_ms``, from the headers'
publish times). A third mode runs the processes with the server's states at 250 Hz (``--param
server.scene.state_rate_hz=250``; issue 19 asks for gaps ≤ 10 ms and a publish → receive p99 ≤ 3 ms
there), and a fourth the same with every node at normal scheduling (``--no-realtime``: the demo's
server and CAN adapter otherwise run their threads ``SCHED_FIFO``, its ``realtime`` keys; the tick
thread then asks for nice -10, as before real time), the baseline of real time. Two more modes run
those two beside ``HOGS`` processes that each burn a core at normal priority (``while True: pass``:
a lab PC's ground station and compiler; issue 43 asks, under two hogs with real time, for a largest
gap ≤ 10 ms and a state p99 ≤ 3 ms). "late ticks" is the server's ``late_ticks`` (a tick published
more than a period after its wall-clock due time) per tick, "tick thread" its ``tick_priority``.
Beside every run, a stall probe (``bench._util.StallProbe``: one thread at ``SCHED_FIFO`` 95, above
every node, waking every 1 ms) records how late the platform itself lets a thread run: a stall it
sees held every process of the run, so no gap or latency of that run can be shorter; and once
alone, before the runs, with nothing of ours running.

A full garbage collection in a node's process: in a fresh interpreter, one of the demo's nodes
is built as its node host builds it (its entry imported, constructed with the launch file's
params on an in-process bus, not started); the CPU time of ``gc.collect()`` (median of 5),
which holds the interpreter lock throughout, before and after
:func:`hil_bridge.lifetime.freeze_heap` (what the node hosts, echo nodes and echo workers do
once built and once started).
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench._util import StallProbe, median, python_json, table
from hil_bridge.bus.domain import claim_first_free

TITLE = "Nodes as processes: start-up, memory and CPU against threads"

ROOT = Path(__file__).resolve().parent.parent
RUN_S = 10.0
REPEAT = 3
#: competing processes in the loaded modes: one busy loop per core, at normal priority
HOGS = 2
_250HZ = ["--param", "server.scene.state_rate_hz=250"]
#: mode -> the launch's extra arguments and how many CPU hogs run beside it
MODES: dict[str, tuple[list[str], int]] = {
    "threads": (["--threads"], 0), "processes": ([], 0),
    "processes, states at 250 Hz": (_250HZ, 0),
    "processes, states at 250 Hz, no real time": ([*_250HZ, "--no-realtime"], 0),
    "processes, states at 250 Hz, two CPU hogs": (_250HZ, HOGS),
    "processes, states at 250 Hz, two CPU hogs, no real time": (
        [*_250HZ, "--no-realtime"], HOGS)}


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def _children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


@contextlib.contextmanager
def _hogs(n: int) -> Iterator[None]:
    """``n`` processes that burn a core each (a ground station, a compiler: a lab PC's load)
    at normal priority while the block runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def _once(mode: str, domain: int) -> dict[str, Any]:
    with _hogs(MODES[mode][1]), StallProbe() as probe:
        result = _launch(mode, domain)
    return result | {"probe": probe.result}


def _launch(mode: str, domain: int) -> dict[str, Any]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(ROOT / "launch" / "demo.yaml"),
         "--domain", str(domain), "--duration", str(RUN_S), "--json", *MODES[mode][0]],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None and proc.stdout is not None
    started = float("nan")
    for line in proc.stderr:
        if "echoloop launch: running" in line:
            started = time.monotonic() - t0
            break
    time.sleep(RUN_S / 2)
    rss = {pid: _rss_mb(pid) for pid in [proc.pid, *_children(proc.pid)]}
    out, _ = proc.communicate(timeout=300)
    ended = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = json.loads(out)
    nodes = summary["nodes"]
    server = nodes["server"]
    sim_s = float(server["sim_time_s"])
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    per_node = {name: rss.get(stats.get("pid", -1), float("nan")) for name, stats in
                nodes.items()} if mode == "processes" else {}
    mon = summary["monitor"]
    return {
        "start_s": started, "stop_s": ended - started - RUN_S, "launcher_mb": rss[proc.pid],
        "total_mb": sum(v for v in rss.values() if v == v), "per_node_mb": per_node,
        "cpu_per_sim_s": cpu / sim_s if sim_s else float("nan"), "sim_s": sim_s,
        "echoes": int(server["echoes_published"]), "exit": summary["exit_status"],
        "ping_echo_p99": mon.get("ping_echo_ms", {}).get("p99", float("nan")),
        "state_p99": mon.get("state_latency_ms", {}).get("p99", float("nan")),
        "autopilot_p99": nodes.get("autopilot", {}).get("state_latency_ms", {}).get(
            "p99", float("nan")),
        "state_gap_max": mon.get("state_gap_ms", {}).get("max", float("nan")),
        "late_pct": 100 * server["late_ticks"] / max(1, server["ticks"]),
        "tick_priority": server.get("tick_priority", ""),
    }


#: builds one of the demo's nodes (argv: its name) and times a full collection before and after
#: the heap is frozen
_GC_PROBE = """
import gc, json, sys, time
from hil_bridge.files.config import load_yaml
from hil_bridge.launch.spec import resolve_entry
from hil_bridge.lifetime import freeze_heap
node = next(n for n in load_yaml("launch/demo.yaml")["nodes"] if n["name"] == sys.argv[1])
built = resolve_entry(node["entry"])(node["name"], bus="mem://gc-probe", **node["params"])
def full_ms():
    times = []
    for _ in range(5):
        t = time.process_time()
        gc.collect()
        times.append(1e3 * (time.process_time() - t))
    return sorted(times)[2]
before, tracked = full_ms(), len(gc.get_objects())
freeze_heap(collect=True)
print(json.dumps({"tracked": tracked, "before_ms": before, "after_ms": full_ms()}))
"""
GC_NODES = ("server", "autopilot", "mock_autopilot_swarm")


def _gc_rows() -> list[list[str]]:
    rows = []
    for name in GC_NODES:
        r = python_json(_GC_PROBE, name)
        rows.append([name, f"{r['tracked']:,}", f"{r['before_ms']:.1f}", f"{r['after_ms']:.3f}"])
    return rows


def run(out_dir: Path) -> str:
    gc_rows = _gc_rows()
    with StallProbe() as idle:
        time.sleep(RUN_S)
    results: dict[str, list[dict[str, Any]]] = {m: [] for m in MODES}
    with claim_first_free() as (dom, _):
        assert dom.number is not None
        for _ in range(REPEAT):
            for mode in MODES:
                results[mode].append(_once(mode, dom.number))
    rows = []
    for mode, runs in results.items():
        def med(key: str, runs: list[dict[str, Any]] = runs) -> float:
            return median([r[key] for r in runs])
        rows.append([mode, f"{med('start_s'):.2f}", f"{med('stop_s'):.2f}",
                     f"{med('total_mb'):.0f}", f"{med('launcher_mb'):.0f}",
                     f"{med('cpu_per_sim_s'):.2f}", f"{med('sim_s'):.1f}", f"{med('echoes'):.0f}",
                     f"{med('ping_echo_p99'):.1f}", f"{med('state_p99'):.2f}",
                     f"{med('autopilot_p99'):.2f}",
                     f"{med('state_gap_max'):.1f}", f"{med('late_pct'):.2f}",
                     runs[0]["tick_priority"], ", ".join(str(r["exit"]) for r in runs)])
    thr, prc = results["threads"], results["processes"]
    ratio = median([r["cpu_per_sim_s"] for r in prc]) / median([r["cpu_per_sim_s"] for r in thr])
    i = idle.result
    probe_rows = [[f"nothing of ours running ({RUN_S:.0f} s, before the runs)", i["policy"],
                   f"{i['p50_us']:.0f}", f"{i['p99_us']:.0f}", f"{i['over_1ms']}",
                   f"{i['over_3ms']}", f"{i['max_ms']:.1f}"]]
    for mode, runs in results.items():
        pr = [r["probe"] for r in runs]
        probe_rows.append([mode, pr[0]["policy"], f"{median([p['p50_us'] for p in pr]):.0f}",
                           f"{median([p['p99_us'] for p in pr]):.0f}",
                           " / ".join(f"{p['over_1ms']}" for p in pr),
                           " / ".join(f"{p['over_3ms']}" for p in pr),
                           " / ".join(f"{p['max_ms']:.1f}" for p in pr)])
    node_rows = []
    names = sorted({n for r in prc for n in r["per_node_mb"]})
    for name in names:
        node_rows.append([name, f"{median([r['per_node_mb'][name] for r in prc]):.0f}"])
    return (
        f"{__doc__.split(chr(10) + chr(10), 1)[1].strip()}\n\n"
        f"### The demo for {RUN_S:.0f} s, medians of {REPEAT} interleaved runs per mode\n\n"
        + table(["mode", "start-up s", "stop s", "RSS all MB", "RSS launcher MB",
                 "CPU s per sim s", "sim s", "echoes", "ping→echo p99 ms",
                 "state p99 ms", "autopilot state p99 ms", "largest state gap ms",
                 "late ticks %", "tick thread",
                 "exit"], rows)
        + f"\n\nCPU per sim second, processes / threads (same run): **{ratio:.2f}**.\n\n"
        "### The platform during these runs (the stall probe: wake-up lateness)\n\n"
        + table(["mode", "probe", "p50 µs", "p99 µs", "late > 1 ms (each run)",
                 "late > 3 ms (each run)", "latest ms (each run)"], probe_rows) + "\n\n"
        "### Resident memory of each node's process (processes mode, MB)\n\n"
        + table(["node", "RSS MB"], node_rows) + "\n\n"
        "### A full garbage collection in a node's process (CPU ms, median of 5)\n\n"
        + table(["node", "objects tracked", "full collection ms",
                 "after freeze_heap ms"], gc_rows) + "\n"
    )
