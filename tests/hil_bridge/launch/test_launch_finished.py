"""``run(..., until_finished=True)`` ends the run once every launchable with an end of its own
(``finished()``) says it is finished, whether the nodes are threads or processes (the host
answers ``finished`` requests); launchables without an end do not hold it, and a run whose
launchables have none runs its duration."""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest

from hil_bridge.bus.domain import Domain, claim_first_free, use
from hil_bridge.launch.runner import run

ENDS = "tests.hil_bridge.launch.endnodes:Ends"
ALLOW = ["tests.hil_bridge.launch.endnodes"]


def _launch(*params: dict[str, Any]) -> dict[str, Any]:
    return {"allow_modules": ALLOW, "nodes": [
        {"name": f"n{i}", "entry": ENDS, "params": p} for i, p in enumerate(params)]}


@pytest.fixture
def domain() -> Iterator[Domain]:
    """A free numbered domain, claimed for the test (its bus crosses processes)."""
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 60 + 20)) as (dom, _), \
            use(dom):
        yield dom


def test_the_run_ends_when_every_node_with_an_end_finished() -> None:
    launch = _launch({"after": 2}, {"after": 6}, {"has_end": False})
    summary = run(launch, bus="mem://finished", duration=60.0, handle_signals=False,
                  until_finished=True)
    assert summary.stopped_by == "finished" and summary.failures == []
    assert summary.nodes["n1"]["asked"] == 6  # the later one decided
    assert summary.nodes["n0"]["asked"] >= 6 and summary.nodes["n2"]["asked"] == 0


def test_without_until_finished_or_an_end_the_duration_holds() -> None:
    for launch, until in ((_launch({"after": 1}), False), (_launch({"has_end": False}), True),
                          (_launch({"after": None}), True)):
        summary = run(launch, bus="mem://finished", duration=0.2, handle_signals=False,
                      until_finished=until)
        assert summary.stopped_by == "duration"


@pytest.mark.processes
def test_nodes_in_processes_answer_finished(domain: Domain) -> None:
    summary = run(_launch({"after": 2}, {"has_end": False}), domain=domain, duration=60.0,
                  handle_signals=False, until_finished=True, processes=True)
    assert summary.mode == "processes"
    assert summary.stopped_by == "finished" and summary.failures == []
    assert summary.nodes["n0"]["asked"] == 2
