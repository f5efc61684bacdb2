"""A launcher killed with -9 at any moment leaves nothing behind (tests/hil_bridge/launch/
killstress.py): one launch of each kind killed at a seeded moment, and the checks themselves
shown to see each kind of leftover. ``python -m bench killstress`` runs thirty."""

from __future__ import annotations

import contextlib
import os
import pty
import secrets
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
)
from hil_bridge.server.shared_tiles import SharedTiles
from tests.hil_bridge.launch import killstress
from tests.hil_bridge.launch.killstress import MARKER, stress

pytestmark = pytest.mark.processes


@pytest.fixture
def domain() -> Iterator[Domain]:
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 60 + 20)) as (dom, _):
        yield dom


def test_the_checks_see_a_process_a_pty_shared_memory_and_a_port_left(domain: Domain) -> None:
    assert domain.number is not None
    token = secrets.token_hex(6)
    shm_before = killstress.shared_entries(domain)
    bus_port = BUS_PORT_BASE + DOMAIN_STRIDE * domain.number
    with contextlib.ExitStack() as undo:
        sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                                   env={**os.environ, MARKER: token})
        undo.callback(sleeper.wait)
        undo.callback(sleeper.kill)
        master, slave = pty.openpty()
        undo.callback(os.close, master)
        undo.callback(os.close, slave)
        link = domain.path("sonar0")
        link.symlink_to(os.ttyname(slave))
        undo.callback(link.unlink, missing_ok=True)
        store = domain.shared_dir("tiles")  # as a server makes its tile store
        undo.callback(SharedTiles(store, []).remove_all)
        port = undo.enter_context(socket.socket())
        port.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as ZeroMQ binds
        port.bind(("127.0.0.1", bus_port))
        port.listen()
        deadline = time.monotonic() + 10.0
        while not killstress.marked(token) and time.monotonic() < deadline:
            time.sleep(0.02)  # the child's environment is readable once it exec'd
        left = killstress.leftovers(token, domain, {os.ttyname(slave)}, shm_before)
        assert left == {"processes": [str(sleeper.pid)],
                        "ptys": [f"link sonar0 -> {os.ttyname(slave)}"],
                        "shared memory": [store.name], "ports": [f"tcp:{bus_port}"]}
        sleeper.kill()
        sleeper.wait()
        link.unlink()
        # no process of the run left: the pty the run's link pointed at must be free too
        held = killstress.leftovers(token, domain, {os.ttyname(slave)}, shm_before)["ptys"]
        assert held == [os.ttyname(slave)]  # this test holds it
    assert not any(killstress.leftovers(token, domain, set(), shm_before).values())


def test_three_launches_killed_at_seeded_moments_leave_nothing_behind() -> None:
    """Seed 1 kills the demo 3.07 s after its spawn (its hosts constructing their nodes, on
    this machine), the echo pool's launch at 5.70 s (running) and the ArduPilot launch at
    0.86 s (the launcher importing)."""
    outcomes = stress(3, seed=1, max_kill_s=6.0, first_domain=20 + os.getpid() % 60)
    assert [o.kind for o in outcomes] == ["demo", "echo pool", "ardupilot"]
    assert [o for o in outcomes if not o.clean] == []
