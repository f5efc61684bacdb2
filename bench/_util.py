"""Small timing and memory helpers shared by the benchmark modules."""

from __future__ import annotations

import io
import json
import statistics
import subprocess
import sys
import tarfile
import time
import tracemalloc
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

#: the repository (benchmarks run from a clone: ``git archive`` finds their baselines there)
ROOT = Path(__file__).resolve().parent.parent


def time_it(
    fn: Callable[[], Any], *, repeat: int = 7, warmup: int = 1, min_seconds: float = 0.0
) -> list[float]:
    """Wall-clock seconds of ``repeat`` calls of ``fn`` after ``warmup`` untimed calls.

    With ``min_seconds`` > 0 the number of calls grows until their total reaches it.
    """
    for _ in range(warmup):
        fn()
    times: list[float] = []
    total = 0.0
    while len(times) < repeat or total < min_seconds:
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        times.append(dt)
        total += dt
    return times


def median(xs: Sequence[float]) -> float:
    return float(statistics.median(xs))


def peak_bytes(fn: Callable[[], Any]) -> tuple[Any, int]:
    """Run ``fn`` under tracemalloc (numpy reports its buffers); return (result, peak bytes)."""
    tracemalloc.start()
    try:
        result = fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return result, peak


def fmt_s(seconds: float) -> str:
    """Human time: 12.3 µs / 4.56 ms / 7.89 s."""
    if seconds < 1e-3:
        return f"{seconds * 1e6:.1f} µs"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def python_json(code: str, *args: str, env: dict[str, str] | None = None) -> dict[str, Any]:
    """Run ``code`` in a fresh interpreter (argv ``args``, from the repository) and return the
    JSON object its last output line holds."""
    out = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True,
                         text=True, env=env, cwd=ROOT)
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def git_tree(commit: str, dest: Path, paths: Sequence[str] = ("sim_core",)) -> bool:
    """Extract ``paths`` of ``commit`` into ``dest`` (a baseline measured in the same run as
    today's code); False where git or the commit is absent (e.g. a tarball, a shallow clone)."""
    try:
        tar = subprocess.run(["git", "-C", str(ROOT), "archive", commit, *paths], check=True,
                             capture_output=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return False
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(dest, filter="data")
    return True


#: a thread above every node (SCHED_FIFO 95 where allowed) sleeping 1 ms at a time until its
#: standard input closes; prints its wake-up lateness (how far past each due time it ran)
_STALL_PROBE = """
import json, os, sys, threading, time
import numpy as np
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(95))
    policy = "fifo 95"
except OSError:
    policy = "normal"
late, stop = [], threading.Event()
def watch():
    sys.stdin.read()
    stop.set()
threading.Thread(target=watch, daemon=True).start()
due = time.monotonic_ns()
while not stop.is_set():
    due += 1_000_000
    time.sleep(max(0.0, (due - time.monotonic_ns()) / 1e9))
    now = time.monotonic_ns()
    late.append(now - due)
    due = max(due, now - 1_000_000)
us = np.array(late, dtype=np.float64) / 1e3
print(json.dumps({"policy": policy, "n": int(us.size), "p50_us": float(np.percentile(us, 50)),
                  "p99_us": float(np.percentile(us, 99)), "max_ms": float(us.max() / 1e3),
                  "over_1ms": int((us > 1e3).sum()), "over_3ms": int((us > 3e3).sum())}))
"""


class StallProbe:
    """The platform's own scheduling stalls while a benchmark runs: a process of its own whose
    one thread (``SCHED_FIFO`` 95 where allowed, above every node, so that nothing of ours
    delays it) sleeps 1 ms at a time and records how late it wakes. A stall it sees stops
    every process (a virtual machine's CPU not running, an interrupt storm), so it floors what
    any node can show in the same window. ``with StallProbe() as probe: ...``, then
    ``probe.result``: policy, n, p50_us, p99_us, max_ms, over_1ms, over_3ms."""

    def __init__(self) -> None:
        self.result: dict[str, Any] = {}
        self._proc: subprocess.Popen[str] | None = None

    def __enter__(self) -> StallProbe:
        self._proc = subprocess.Popen([sys.executable, "-c", _STALL_PROBE], cwd=ROOT,
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._proc is not None
        out, _ = self._proc.communicate(input="", timeout=60)
        self.result = dict(json.loads(out.strip().splitlines()[-1]))
