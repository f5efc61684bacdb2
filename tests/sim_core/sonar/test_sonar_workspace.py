"""Scratch memory of the synthesis: reuse never changes an echo, concurrent calls never share it."""

from __future__ import annotations

import math
import threading

import numpy as np

from sim_core.sonar import Beam, EchoParams, Workspace, synthesize
from sim_core.sonar.workspace import SCRATCH_MAX_BYTES, borrowed
from tests.sim_core.sonar._scenes import cone_cloud

BEAM = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(30.0))
#: (leaves, seed, fidelity, params): scenes of different sizes, so a reused workspace holds
#: longer arrays than the next echo needs, and every scratch user runs
CASES = [
    (3000, 1, "fast", EchoParams()),
    (200, 2, "fast", EchoParams(beam_model="incident_freq")),
    (5000, 3, "realtime", EchoParams(budget_s=2e-3)),
    (300, 4, "reference", EchoParams()),
    (1500, 5, "fast", EchoParams(shading=True)),
]


def _echo(case: tuple[int, int, str, EchoParams], ws: Workspace | None) -> np.ndarray:
    m, seed, fidelity, params = case
    leaves = cone_cloud(m, seed=seed, half_angle_deg=25.0, r_lo=0.5, r_hi=8.0)
    return synthesize(leaves, BEAM, params, fidelity=fidelity, workspace=ws).samples


def test_a_reused_workspace_gives_the_echoes_of_fresh_ones() -> None:
    fresh = [_echo(case, Workspace()) for case in CASES]
    ws = Workspace()
    for _ in range(2):
        for case, expected in zip(CASES, fresh, strict=True):
            np.testing.assert_array_equal(_echo(case, ws), expected)
    for case, expected in zip(CASES, fresh, strict=True):
        np.testing.assert_array_equal(_echo(case, None), expected)


def test_an_echo_does_not_alias_its_workspace() -> None:
    ws = Workspace()
    first = _echo(CASES[0], ws)
    kept = first.copy()
    _echo(CASES[2], ws)
    np.testing.assert_array_equal(first, kept)


def test_workspace_arrays_are_reused_by_name_and_dtype() -> None:
    ws = Workspace()
    a = ws.array("x", (10, 3), np.float32)
    assert a.shape == (10, 3) and a.dtype == np.float32
    assert np.shares_memory(a, ws.array("x", 7, np.float32))
    assert not np.shares_memory(a, ws.array("x", 7, np.float64))
    assert not np.shares_memory(a, ws.array("y", 7, np.float32))
    big = SCRATCH_MAX_BYTES // 8 + 1
    assert not np.shares_memory(ws.array("z", big, np.float64), ws.array("z", big, np.float64))


def test_borrowed_workspaces_are_never_held_twice_at_once() -> None:
    with borrowed() as a, borrowed() as b:
        assert a is not b
    with borrowed() as c:
        assert c in (a, b)


def test_echoes_synthesised_in_threads_at_once_are_the_sequential_ones() -> None:
    expected = [_echo(case, None) for case in CASES]
    results: dict[tuple[int, int], np.ndarray] = {}
    errors: list[BaseException] = []
    start = threading.Barrier(4)

    def work(k: int) -> None:
        try:
            start.wait(timeout=60)
            for i in range(len(CASES)):
                j = (i + k) % len(CASES)
                results[(k, j)] = _echo(CASES[j], None)
        except BaseException as exc:  # reported below, in the test's thread
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert not any(t.is_alive() for t in threads)
    assert len(results) == 4 * len(CASES)
    for (_, j), samples in results.items():
        np.testing.assert_array_equal(samples, expected[j])
