"""A seeded kill stress: launches killed with SIGKILL at random moments, and what each left.

:func:`stress` runs ``count`` launches in turn, cycling through :data:`KINDS` (the closed-loop
demo; the sonar forest with its echoes computed by an echo pool of two worker processes and a
shared tile store; the ArduPilot glider launch, its SITL played by
:class:`~drivers.mocks.sitl_double.SitlDouble` from this process). Each is ``python -m
hil_bridge.cli launch FILE --domain N`` in a free domain of its own, SIGKILLed (the launcher
alone: its children must go by themselves) ``kill_at_s`` seconds after it was spawned, drawn
from a seeded numpy Generator between 0 and ``max_kill_s``, so that kills land in the imports,
the construction of the nodes, their start and the steady run alike. Then, for up to
``wait_s`` seconds (the bound: a node host given SIGTERM by the kernel has
``hil_bridge.launch.host.STOP_GRACE_S`` to stop its nodes before SIGALRM ends it), it looks for
what the run left:

* ``processes``: any live process whose environment carries the run's marker (every process of
  a launch inherits the launcher's environment: hosts, echo workers);
* ``ptys``: a pty link left in the domain's directory, or a pty any such link pointed at while
  the run went that a process still holds open;
* ``shared memory``: an entry of the domain's directory in ``/dev/shm`` (tile stores, pose
  rings) that was not there before;
* ``ports``: a TCP port of the domain's listening, or a UDP port of the domain's bound
  (``/proc/net/{tcp,udp}{,6}``): the bus pair, the live view, CAN multicast, SITL's.

The test (``test_kill_stress.py``) runs one launch of each kind; ``python -m bench killstress``
runs thirty.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.mocks.sitl_double import SitlDouble, WingLeveler
from hil_bridge.bus.domain import (
    BUS_PORT_BASE,
    DOMAIN_STRIDE,
    LIVE_PORT_BASE,
    Domain,
    claim_first_free,
    shared_root,
)
from tests.hil_bridge.server._killed import alive

ROOT = Path(__file__).resolve().parents[3]
#: the environment variable that marks every process of one stress launch
MARKER = "ECHOLOOP_KILLSTRESS"
#: the line the launcher writes once every node runs
RUNNING = "echoloop launch: running"


@dataclass(frozen=True, slots=True)
class Kind:
    """A launch file of the repository, the arguments it runs with, and whether it needs a
    SITL peer (flown from this process)."""

    file: str
    args: tuple[str, ...] = ()
    sitl: bool = False


KINDS: dict[str, Kind] = {
    "demo": Kind("launch/demo.yaml"),
    "echo pool": Kind("launch/sonar_forest.yaml", ("--param", "server.echo_worker=pool",
                                                   "--param", "server.echo_workers=2")),
    "ardupilot": Kind("launch/ardupilot_glider.yaml", sitl=True),
}


@dataclass(slots=True)
class Outcome:
    """One launch killed: its kind, when (s after spawn), whether every node ran by then
    (``running``), how many processes of it were seen alive just before the kill, what it left
    (by check; empty lists when clean) and how long after the kill the last of it went."""

    kind: str
    domain: int
    kill_at_s: float
    running: bool
    processes_seen: int
    left: dict[str, list[str]] = field(default_factory=dict)
    clean_after_s: float | None = None

    @property
    def clean(self) -> bool:
        return not any(self.left.values())


def marked(token: str) -> list[int]:
    """Live processes whose environment holds ``MARKER=token``."""
    needle = f"{MARKER}={token}".encode()
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                env = f.read().split(b"\0")
        except OSError:
            continue
        if needle in env and alive(int(entry)):
            found.append(int(entry))
    return found


def domain_ports(number: int) -> tuple[set[int], set[int]]:
    """The TCP and UDP ports domain ``number``'s defaults bind (:mod:`hil_bridge.bus.domain`)."""
    base = BUS_PORT_BASE + DOMAIN_STRIDE * number
    tcp = {base, base + 1, LIVE_PORT_BASE + DOMAIN_STRIDE * number, 5760 + DOMAIN_STRIDE * number,
           5762 + DOMAIN_STRIDE * number, 4560 + number}
    udp = {base + 2, 9002 + DOMAIN_STRIDE * number}
    return tcp, udp


def bound_ports(number: int) -> list[str]:
    """Domain ``number``'s TCP ports in LISTEN and UDP ports bound, as ``"tcp:7400"``."""
    tcp, udp = domain_ports(number)
    out = set()
    for proto, wanted in (("tcp", tcp), ("udp", udp)):
        for table in (proto, proto + "6"):
            with contextlib.suppress(OSError), open(f"/proc/net/{table}") as f:
                for line in f.readlines()[1:]:
                    cols = line.split()
                    port = int(cols[1].rsplit(":", 1)[1], 16)
                    if port in wanted and (proto == "udp" or cols[3] == "0A"):
                        out.add(f"{proto}:{port}")
    return sorted(out)


def _pty_links(domain: Domain) -> dict[str, str]:
    """The domain directory's links to ptys: name -> target."""
    links = {}
    with contextlib.suppress(OSError):
        for entry in domain.dir().iterdir():
            if entry.is_symlink():
                with contextlib.suppress(OSError):
                    target = os.readlink(entry)
                    if target.startswith("/dev/pts/"):
                        links[entry.name] = target
    return links


def _held(ptys: set[str]) -> list[str]:
    """Which of the ptys ``ptys`` a process of this user still holds open."""
    held = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        with contextlib.suppress(OSError):
            for fd in os.listdir(f"/proc/{entry}/fd"):
                with contextlib.suppress(OSError):
                    target = os.readlink(f"/proc/{entry}/fd/{fd}")
                    if target in ptys:
                        held.add(target)
    return sorted(held)


def shared_entries(domain: Domain) -> set[str]:
    """The names in the domain's directory of files shared in memory."""
    where = shared_root() / domain.token
    return {p.name for p in where.iterdir()} if where.is_dir() else set()


def leftovers(token: str, domain: Domain, ptys: set[str],
              shm_before: set[str]) -> dict[str, list[str]]:
    """What the run marked ``token`` left in ``domain``, by check (module docstring): ``ptys``
    are those its links pointed at, ``shm_before`` the shared entries there before it."""
    assert domain.number is not None
    procs = marked(token)
    return {"processes": [str(p) for p in procs],
            "ptys": [f"link {n} -> {t}" for n, t in _pty_links(domain).items()]
            + ([] if procs else _held(ptys)),
            "shared memory": sorted(shared_entries(domain) - shm_before),
            "ports": bound_ports(domain.number)}


@contextlib.contextmanager
def _sitl_peer(domain: Domain) -> Iterator[None]:
    """SITL's side for the block: frames to the domain's SITL port, resent while no answer
    comes (the node not up yet, or gone), about one every 4 ms."""
    assert domain.number is not None
    stop = threading.Event()
    double = SitlDouble(port=9002 + DOMAIN_STRIDE * domain.number, timeout_s=0.2)
    pilot = WingLeveler(bank_deg=10.0)

    def fly() -> None:
        while not stop.wait(0.004):
            with contextlib.suppress(OSError):
                double.frame(pilot(double.last))

    thread = threading.Thread(target=fly, name="killstress-sitl", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=5.0)
        double.close()


def launch_and_kill(name: str, domain: Domain, kill_at_s: float, *,
                    wait_s: float = 30.0) -> Outcome:
    """Launch kind ``name`` in ``domain`` (claimed by the caller), SIGKILL the launcher
    ``kill_at_s`` s after spawning it, and wait up to ``wait_s`` s for nothing of it to be
    left (module docstring)."""
    assert domain.number is not None
    kind = KINDS[name]
    token = secrets.token_hex(6)
    shm_before = shared_entries(domain)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1",
           "ECHOLOOP_DOMAIN": str(domain.number), MARKER: token}
    ptys: set[str] = set()
    with tempfile.TemporaryFile("w+") as err, (
            _sitl_peer(domain) if kind.sitl else contextlib.nullcontext()):
        t0 = time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, "-m", "hil_bridge.cli", "launch", str(ROOT / kind.file),
             "--domain", str(domain.number), "--duration", "600", *kind.args],
            cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        try:
            while (left := kill_at_s - (time.monotonic() - t0)) > 0:
                ptys.update(_pty_links(domain).values())
                time.sleep(min(0.05, left))
            seen = len(marked(token))
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        killed = time.monotonic()
        err.seek(0)
        running = RUNNING in err.read()
    outcome = Outcome(name, domain.number, kill_at_s, running, seen)
    deadline = killed + wait_s
    while True:
        outcome.left = leftovers(token, domain, ptys, shm_before)
        if outcome.clean or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    if outcome.clean:
        outcome.clean_after_s = time.monotonic() - killed
    for pid in marked(token):  # what outlived the bound goes now, so the next launch is judged
        with contextlib.suppress(ProcessLookupError):  # on its own
            os.kill(pid, signal.SIGKILL)
    return outcome


def kill_times(count: int, seed: int, max_kill_s: float) -> list[float]:
    """The ``count`` kill moments (s after spawn) of seed ``seed``, uniform on [0, max_kill_s)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    return [float(t) for t in rng.uniform(0.0, max_kill_s, size=count)]


def stress(count: int, seed: int, *, max_kill_s: float, wait_s: float = 30.0,
           first_domain: int = 20) -> list[Outcome]:
    """``count`` launches cycling through :data:`KINDS`, each killed at its moment of
    :func:`kill_times`, each in the first free domain from ``first_domain``."""
    kinds = list(KINDS)
    outcomes = []
    for i, at in enumerate(kill_times(count, seed, max_kill_s)):
        with claim_first_free(Domain(first_domain)) as (dom, _):
            outcomes.append(launch_and_kill(kinds[i % len(kinds)], dom, at, wait_s=wait_s))
    return outcomes
