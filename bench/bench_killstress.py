"""Kill stress: thirty launches killed with SIGKILL at seeded random moments, and what they left.

``tests/hil_bridge/launch/killstress.py`` holds the machinery: launches cycling through the
closed-loop demo, the sonar forest with an echo pool (two workers, a shared tile store) and the
ArduPilot glider launch (SITL played by the protocol double), each ``echoloop launch`` in a free
domain of its own, its launcher SIGKILLed ``U(0, MAX_KILL_S)`` s after its spawn (numpy
Generator of seed ``SEED``), then every process of the run, pty, ``/dev/shm`` entry of its
domain and bound port of its domain looked for, for up to ``WAIT_S`` s. The suite runs one of
each kind (``tests/hil_bridge/launch/test_kill_stress.py``).
"""

from __future__ import annotations

from pathlib import Path

from bench._util import median, table
from tests.hil_bridge.launch.killstress import KINDS, Outcome, stress

TITLE = "Kill stress: launches killed with -9 at random moments, what they left"

COUNT = 30
SEED = 0
#: kills land from the launcher's imports to well into the steady run (the demo runs ~3-10 s
#: after its spawn on this machine, depending on its load)
MAX_KILL_S = 15.0
#: how long the run's processes may take to go (a host's STOP_GRACE_S is 20 s)
WAIT_S = 30.0


def _rows(outcomes: list[Outcome]) -> list[list[str]]:
    rows = []
    for kind in KINDS:
        mine = [o for o in outcomes if o.kind == kind]
        clean = [o for o in mine if o.clean]
        after = [o.clean_after_s for o in clean if o.clean_after_s is not None]
        rows.append([
            kind, str(len(mine)), f"{len(clean)}/{len(mine)}",
            str(sum(not o.running for o in mine)), str(sum(o.running for o in mine)),
            f"{median([float(o.processes_seen) for o in mine]):.0f}",
            f"{median(after):.2f}" if after else "-", f"{max(after):.2f}" if after else "-",
        ])
    return rows


def report(outcomes: list[Outcome]) -> str:
    """The section's Markdown for ``outcomes``."""
    clean = sum(o.clean for o in outcomes)
    leaks = [f"- {o.kind} in domain {o.domain}, killed at {o.kill_at_s:.2f} s "
             f"({'running' if o.running else 'starting'}): "
             + "; ".join(f"{k} {v}" for k, v in o.left.items() if v) for o in outcomes
             if not o.clean]
    return (
        f"{len(outcomes)} launches (cycling {', '.join(KINDS)}), each launcher SIGKILLed at a "
        f"moment drawn uniformly from [0, {MAX_KILL_S:g}) s after its spawn (seed {SEED}); "
        f"left = a live process of the run, a pty link or a pty held, a `/dev/shm` entry or a "
        f"bound port of its domain, looked for up to {WAIT_S:g} s after the kill.\n\n"
        f"**{clean}/{len(outcomes)} clean.**\n\n"
        + table(["launch", "runs", "clean", "killed starting", "killed running",
                 "processes at the kill (median, launcher included)",
                 "gone after (s, median)", "gone after (s, max)"], _rows(outcomes))
        + ("\n\nLeft behind:\n\n" + "\n".join(leaks) if leaks else "")
    )


def run(out_dir: Path) -> str:
    return report(stress(COUNT, SEED, max_kill_s=MAX_KILL_S, wait_s=WAIT_S))
