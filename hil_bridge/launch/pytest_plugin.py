"""The echoloop pytest plugin: the ``echoloop_launch`` fixture for users' CI (docs/testing.md).

Installed with the distribution (entry point ``pytest11``: ``echoloop``), so any project that
``pip install``-s echoloop can write::

    def test_my_controller(echoloop_launch):
        summary = echoloop_launch("launch/my_loop.yaml", duration=5.0,
                                  params={"server.scene.clock.mode": "lockstep"},
                                  expect=["server.stalls == 0"])
        assert summary.nodes["server"]["gliders_alive"] == 8

``echoloop_launch(path_or_dict, duration=5.0, params=None, *, expect=(),
allow_disconnected=False, record=None)`` runs a launch file (or an already parsed launch
mapping) in this process, exactly as ``echoloop launch`` does, in a *private domain*
(:meth:`hil_bridge.bus.domain.Domain.private`): its own ``mem://`` bus (replacing the file's),
python-can virtual channels and pty links under the test's ``tmp_path``, so pytest-xdist
workers, and several runs in one test, never share anything. ``params`` overrides node
parameters like ``--param``: ``{"NODE.KEY": value}`` or ``{"NODE": {"KEY": value}}`` (dotted
keys reach nested parameters). It returns the :class:`hil_bridge.launch.runner.RunSummary` (what
``--json`` prints; ``summary.nodes[name][counter]``). A node that refuses its params raises
the ``ConfigError`` (a ``ValueError``) naming it; a run with failures (a node that failed: its
constructor or ``start()`` raised, or its ``failure()`` named a fault; an expectation that did
not hold; a hardware link that never connected unless ``allow_disconnected``; anything else
that would make ``echoloop launch`` exit non-zero) raises :class:`RunFailed` naming each one.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from hil_bridge.errors import HilError

if TYPE_CHECKING:  # the runner is imported when a test asks for the fixture, not by pytest
    from hil_bridge.launch.runner import RunSummary

__all__ = ["RunFailed", "echoloop_launch", "node_overrides"]


class RunFailed(HilError, AssertionError):
    """A run ended with failures; ``summary`` is its
    :class:`~hil_bridge.launch.runner.RunSummary`."""

    def __init__(self, summary: RunSummary) -> None:
        lines = [f"  {f.message}" for f in summary.failures]
        super().__init__(
            f"echoloop run failed (exit status {summary.exit_status}):\n" + "\n".join(lines)
        )
        self.summary = summary


def node_overrides(params: Mapping[str, Any] | None) -> dict[str, dict[str, Any]]:
    """``{"server.scene.seed": 3}`` or ``{"server": {"scene.seed": 3}}`` -> per-node dotted
    overrides for :func:`hil_bridge.launch.runner.load` (``ValueError`` on any other form)."""
    out: dict[str, dict[str, Any]] = {}
    for key, value in (params or {}).items():
        node, sep, rest = str(key).partition(".")
        if sep and rest:
            out.setdefault(node, {})[rest] = value
        elif isinstance(value, Mapping):
            for sub, v in value.items():
                out.setdefault(node, {})[str(sub)] = v
        else:
            raise ValueError(f"params[{key!r}]: expected 'NODE.KEY' or NODE -> {{KEY: value}}")
    return out


@pytest.fixture
def echoloop_launch(tmp_path: Path) -> Callable[..., RunSummary]:
    """Run a launch description in a private domain and return its summary (module doc)."""
    runs = itertools.count()

    def launch(
        path_or_dict: str | Path | Mapping[str, Any],
        duration: float = 5.0,
        params: Mapping[str, Any] | None = None,
        *,
        expect: Iterable[str] = (),
        allow_disconnected: bool = False,
        record: str | Path | None = None,
    ) -> RunSummary:
        from hil_bridge.bus.domain import Domain
        from hil_bridge.launch.runner import load, run

        domain = Domain.private(tmp_path / f"echoloop-run{next(runs)}")
        spec = load(path_or_dict, params_overrides=node_overrides(params))
        summary = run(spec, duration=duration, bus=domain.bus_url, domain=domain, live=False,
                      record=record, handle_signals=False, expect=list(expect),
                      allow_disconnected=allow_disconnected)
        if summary.failures:
            raise RunFailed(summary)
        return summary

    return launch
