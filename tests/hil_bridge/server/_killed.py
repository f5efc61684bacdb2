"""A server killed with SIGKILL in a process of its own, for the tests of what outlives it."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, exited but not yet reaped, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def kill_server(script: Path, domain_dir: Path, *, wait_s: float = 20.0) -> tuple[str, list[int]]:
    """Run ``script`` (it starts a server in a private domain at ``domain_dir`` and prints that
    domain's token and its child processes' pids), SIGKILL it, and wait up to ``wait_s`` for
    those children to exit. Returns (token, the children still alive then)."""
    proc = subprocess.Popen([sys.executable, str(script), str(domain_dir)],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = proc.stdout.readline().split() if proc.stdout else []
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        if proc.stdout:
            proc.stdout.close()
    token, children = line[0], [int(p) for p in line[1:]]
    assert len(children) == 2, line
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and any(alive(p) for p in children):
        time.sleep(0.05)
    return token, [p for p in children if alive(p)]
