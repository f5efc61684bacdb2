"""A launcher killed with -9 at any moment leaves nothing behind (tests/hil_bridge/launch/
killstress.py): one launch of each kind killed at a seeded moment, and the checks themselves
shown to see each kind of leftover. ``python -m bench killstress`` runs thirty."""

from __future__ import annotations

import os
import pty
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

from hil_bridge.bus.domain import (
    BUS_PORT_BASE,
    DOMAIN_STRIDE,
    Domain,
    claim_first_free,
    shared_root,
)
from tests.hil_bridge.launch import killstress
from tests.hil_bridge.launch.killstress import MARKER, stress

pytestmark = pytest.mark.processes


@pytest.fixture
def domain() -> Iterator[Domain]:
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 60 + 20)) as (dom, _):
        yield dom


def test_the_checks_see_a_process_a_pty_shared_memory_and_a_port_left(domain: Domain) -> None:
    assert domain.number is not None
    token = "planted"
    shm_before = killstress.shared_entries(domain)
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                               env={**os.environ, MARKER: token})
    master, slave = pty.openpty()
    link = domain.path("sonar0")
    link.symlink_to(os.ttyname(slave))
    store = shared_root() / domain.token / "tiles-1-planted"
    store.mkdir(parents=True)
    port = socket.socket()
    port.bind(("127.0.0.1", BUS_PORT_BASE + DOMAIN_STRIDE * domain.number))
    port.listen()
    try:
        deadline = time.monotonic() + 10.0
        while not killstress.marked(token) and time.monotonic() < deadline:
            time.sleep(0.02)  # the child's environment is readable once it exec'd
        left = killstress.leftovers(token, domain, {os.ttyname(slave)}, shm_before)
        assert left == {"processes": [str(sleeper.pid)],
                        "ptys": [f"link sonar0 -> {os.ttyname(slave)}"],
                        "shared memory": ["tiles-1-planted"],
                        "ports": [f"tcp:{BUS_PORT_BASE + DOMAIN_STRIDE * domain.number}"]}
        sleeper.send_signal(signal.SIGKILL)
        sleeper.wait()
        link.unlink()
        # no process of the run left: the pty the run's link pointed at must be free too
        held = killstress.leftovers(token, domain, {os.ttyname(slave)}, shm_before)["ptys"]
        assert held == [os.ttyname(slave)]  # this test holds it
    finally:
        sleeper.kill()
        sleeper.wait()
        port.close()
        os.close(master)
        os.close(slave)
        link.unlink(missing_ok=True)
        store.rmdir()
    assert not any(killstress.leftovers(token, domain, set(), shm_before).values())


def test_three_launches_killed_at_seeded_moments_leave_nothing_behind() -> None:
    """Seed 1 kills the demo 3.07 s after its spawn (its hosts constructing their nodes, on
    this machine), the echo pool's launch at 5.70 s (running) and the ArduPilot launch at
    0.86 s (the launcher importing)."""
    outcomes = stress(3, seed=1, max_kill_s=6.0, first_domain=20 + os.getpid() % 60)
    assert [o.kind for o in outcomes] == ["demo", "echo pool", "ardupilot"]
    assert [o for o in outcomes if not o.clean] == []
