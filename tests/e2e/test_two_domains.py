"""Two `echoloop launch launch/demo.yaml` processes in two domains at once on one machine.

Each binds its domain's ZeroMQ ports, makes its pty link in its domain's directory and uses
its domain's virtual CAN channel; neither sees the other's messages.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from hil_bridge.bus.domain import DOMAIN_ENV, MAX_DOMAIN, Domain, claim_first_free

pytestmark = pytest.mark.processes

ROOT = Path(__file__).resolve().parents[2]


def _two_free_domains(stack: contextlib.ExitStack) -> tuple[Domain, Domain]:
    """Two free domains from a random start, claimed for the test (another run on the machine,
    such as a second test suite, cannot pick them until the test ends)."""
    start = random.SystemRandom().randint(50, MAX_DOMAIN - 20)  # not the global random: a
    # test plugin (hypothesis) reseeds it, so every run would start from the same domain
    first, _ = stack.enter_context(claim_first_free(Domain(start)))
    assert first.number is not None
    second, _ = stack.enter_context(claim_first_free(Domain(first.number + 1)))
    return first, second


def _launch(domain: Domain) -> subprocess.Popen[str]:
    env = {k: v for k, v in os.environ.items() if k != DOMAIN_ENV}
    return subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", "launch/demo.yaml", "--domain",
         str(domain.number), "--duration", "5", "--json"],
        cwd=ROOT, env={**env, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True,
    )


def test_two_demo_launches_in_two_domains_run_at_once_without_interfering() -> None:
    results: list[dict[str, Any]] = []
    with contextlib.ExitStack() as stack:
        domains = _two_free_domains(stack)
        procs = [_launch(d) for d in domains]
        try:
            for proc in procs:
                out, err = proc.communicate(timeout=150)
                assert proc.returncode == 0, err
                results.append(json.loads(out))
        finally:
            for proc in procs:  # SIGTERM: a launch stops cleanly and takes its links with it
                if proc.poll() is None:
                    proc.terminate()
                    try:
                        proc.wait(30)
                    except subprocess.TimeoutExpired:
                        proc.kill()
                        proc.wait()
    for domain, summary in zip(domains, results, strict=True):
        assert summary["domain"] == str(domain)
        assert summary["bus"] == domain.bus_url
        assert summary["exit_status"] == 0 and summary["failures"] == []
        links = summary["links"]
        assert links["sonar_head.serial"]["target"] == str(domain.path("sonar0"))
        group, _ = domain.can_multicast()
        assert links["autopilot.can"]["target"] == f"udp_multicast:{group}"
        assert all(link["connected"] for link in links.values())
        nodes = summary["nodes"]
        server, head, adapter = nodes["server"], nodes["sonar_head_mock"], nodes["sonar_head"]
        assert server["tick_error"] == ""
        assert head["echoes_complete"] >= 5 and head["echoes_incomplete"] == 0
        # only this run's head pinged this run's server, only its autopilots commanded it (the
        # messages in flight when the run stopped may be missing, nothing more)
        assert adapter["pings_in"] - 1 <= server["pings_received"] <= adapter["pings_in"]
        can = nodes["autopilot"]
        sent = (can["cmd_forwarded"] + can.get("cmd_hold_published", 0)
                + can.get("cmd_failsafe_published", 0))
        assert sent - 9 <= server["cmd_received"] <= sent
        assert summary["monitor"]["seq_gaps"] == 0
        states = [t for t in summary["monitor"]["topics"] if t.endswith("/state")]
        assert len(states) == 9
    assert not (domains[0].path("sonar0").is_symlink() or domains[1].path("sonar0").is_symlink())
