"""What a launch run produced (:class:`RunSummary`) and how it is judged (:func:`judge`).

**Exit status** (:attr:`RunSummary.exit_status`, computed in one place, :func:`judge`, from the
summary's ``failures``): 0 all well; otherwise the lowest code among the failures —
:data:`EXIT_FAILED` (1) a node or the recorder failed (its ``failure()``, its constructor,
``start()``, ``stop()`` or ``stats()`` raised), :data:`EXIT_DISCONNECTED` (3) a hardware link
(a node's ``stats()["links"]`` entry) never connected, unless ``allow_disconnected``,
:data:`EXIT_EXPECT` (4) an expectation (:mod:`hil_bridge.launch.expect`) did not hold,
:data:`EXIT_AFTER_RUN` (5) a step after the run (``run(after_run=...)``: ``--plot``) failed
while the run itself went well: such a step never hides or replaces the run's own status.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hil_bridge.launch.expect import Expectation

__all__ = [
    "EXIT_AFTER_RUN",
    "EXIT_DISCONNECTED",
    "EXIT_EXPECT",
    "EXIT_FAILED",
    "EXIT_OK",
    "Failure",
    "RunSummary",
    "collect_links",
    "judge",
]

#: exit status of a run that went well
EXIT_OK = 0
#: a node or the recorder failed
EXIT_FAILED = 1
#: a hardware link (serial port, CAN bus) never connected during the run
EXIT_DISCONNECTED = 3
#: an expectation (``--expect``) did not hold
EXIT_EXPECT = 4
#: the run went well but a step after it (``--plot``) failed
EXIT_AFTER_RUN = 5


@dataclass(frozen=True, slots=True)
class Failure:
    """One reason a run did not go well: its exit ``code``, where it came from (a node name,
    ``node.link``, ``expect``) and one line saying what happened."""

    code: int
    source: str
    message: str


@dataclass(slots=True)
class RunSummary:
    """What a run produced: wall time, why it stopped, per-node stats, bus-level monitor counts,
    the stats of the recorder / live view when they ran (``extras``, by name), the run's domain
    and bus, every hardware link's state (``links``, ``"node.label"`` -> the node's report),
    the ``failures`` that decide :attr:`exit_status`, whether the nodes ran as
    ``"processes"`` or ``"threads"`` (``mode``), and the nodes that shared a process
    (``containers``: container name -> its nodes, composed: :mod:`hil_bridge.bus.intra`)."""

    wall_s: float
    stopped_by: str
    nodes: dict[str, dict[str, Any]]
    monitor: dict[str, Any] = field(default_factory=dict)
    record: str | None = None
    extras: dict[str, dict[str, Any]] = field(default_factory=dict)
    domain: str = ""
    bus: str = ""
    links: dict[str, dict[str, Any]] = field(default_factory=dict)
    failures: list[Failure] = field(default_factory=list)
    mode: str = "threads"
    containers: dict[str, list[str]] = field(default_factory=dict)

    @property
    def exit_status(self) -> int:
        """0 when nothing failed, else the lowest code among :attr:`failures`."""
        return min((f.code for f in self.failures), default=EXIT_OK)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["exit_status"] = self.exit_status
        return out


def collect_links(nodes: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Every node's ``stats()["links"]`` under ``"node.label"``.

    A link report is ``{"kind": "serial" | "can", "target": str, "connected": bool (ever during
    the run), "state": str (at the end of the run), "error": str}``.
    """
    out: dict[str, dict[str, Any]] = {}
    for name, stats in nodes.items():
        links = stats.get("links")
        if isinstance(links, Mapping):
            for label, report in links.items():
                out[f"{name}.{label}"] = dict(report)
    return out


def judge(
    summary: RunSummary, *, expectations: Sequence[Expectation] = (),
    allow_disconnected: bool = False, failed: Sequence[tuple[str, str]] = (),
    after_run: Sequence[tuple[str, str]] = (),
) -> list[Failure]:
    """The one place that decides what failed in a run (and so its exit status).

    ``failed`` holds ``(source, reason)`` for launchables (nodes, the recorder) that reported
    failing (their optional ``failure()``) or whose constructor, ``start()``, ``stop()`` or
    ``stats()`` raised; ``after_run`` ``(step, reason)`` for steps after the run that failed
    (:data:`EXIT_AFTER_RUN`, above every code of the run itself)."""
    failures = [Failure(EXIT_FAILED, source, f"{source} failed: {reason}")
                for source, reason in failed]
    if not allow_disconnected:
        for key, link in summary.links.items():
            if not link.get("connected"):
                why = link.get("error") or "no error reported"
                failures.append(Failure(
                    EXIT_DISCONNECTED, key,
                    f"{key}: {link.get('kind', 'hardware')} link {link.get('target', '?')} never "
                    f"connected during the run ({why}); --allow-disconnected accepts that",
                ))
    for expectation in expectations:
        problem = expectation.check(summary.nodes)
        if problem is not None:
            failures.append(Failure(EXIT_EXPECT, "expect", problem))
    failures += [Failure(EXIT_AFTER_RUN, step, f"{step} failed after the run: {reason}")
                 for step, reason in after_run]
    return failures
