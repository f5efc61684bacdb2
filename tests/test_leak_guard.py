"""The suite's leak guard (tests/conftest.py) fails the test that leaves an echo worker or a
shared tile store behind, and cleans up after it so the next test is judged on its own."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

INNER = '''
import threading, time
from hil_bridge.server.echo_pool import ProcessPool
from hil_bridge.files.scene import load_scene

SCENE = {"forest": {"preset": "seed000-fig5d", "tiled": True, "tile_size_m": 10.0},
         "sonars": [{"id": 0, "mount": 1}],
         "vehicles": [{"id": 1, "path": {"kind": "points", "points": [[2, 5, 2], [18, 5, 2]]}}]}


def test_leaves_a_pool_running():
    pool = ProcessPool(load_scene(SCENE), 1, threading.Event())
    assert pool.store is not None and pool.store.directory.exists()


def test_a_clean_test_after_it():
    pass


def test_closes_its_pool():
    pool = ProcessPool(load_scene(SCENE), 1, threading.Event())
    pool.close()
'''


def test_the_leak_guard_fails_the_test_that_leaks_a_worker_or_a_tile_store(
    pytester: pytest.Pytester,
) -> None:
    pytester.makeconftest((Path(__file__).parent / "conftest.py").read_text(encoding="utf-8"))
    pytester.makepyfile(test_inner=INNER)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-q")
    # the leaking test's body passes, its teardown errors; the two others pass
    result.assert_outcomes(passed=3, errors=1)
    result.stdout.fnmatch_lines(["E*Failed: test leaked echo workers*shared tile stores*tiles-*",
                                 "ERROR test_inner.py::test_leaves_a_pool_running*"])
