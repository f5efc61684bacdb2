"""Suite-wide fixtures: where the test data live, a private domain, and guards against leaked
threads, echo worker processes and shared memory."""

from __future__ import annotations

import os
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.bus.domain import Domain, use

DATA = Path(__file__).resolve().parent / "data"


def pytest_report_header() -> str:
    """Which of numpy's SIMD paths this run takes (float results differ in the last bit)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    active = [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]
    off = os.environ.get("NPY_DISABLE_CPU_FEATURES", "")
    return f"numpy {np.__version__}, SIMD dispatch {active or 'baseline only'}" + (
        f" (NPY_DISABLE_CPU_FEATURES={off})" if off else ""
    )


#: tests that hold no float result numpy's SIMD path could change (lifecycle, framing, the bus,
#: bad files' one-line errors, the recorder's failures and recovery, the repository's own
#: checks): marked ``no_simd_float``, so the AVX-512-off pass of ``.ci/run`` leaves them out, as
#: it leaves out the ``processes`` tests
NO_SIMD_FLOAT = ("hil_bridge/launch/", "hil_bridge/bus/", "hil_bridge/tools/", "drivers/serial/",
                 "hil_bridge/cli/test_cli_bad_inputs.py", "hil_bridge/cli/test_cli_dispatch.py",
                 "hil_bridge/recording/test_bag_recorder.py",
                 "hil_bridge/recording/test_bag_recover.py",
                 "test_plugin.py", "test_leak_guard.py", "test_self_contained.py",
                 "test_architecture.py", "test_docs_figures.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the tests of :data:`NO_SIMD_FLOAT`."""
    root = Path(__file__).resolve().parent
    for item in items:
        where = item.path.resolve().relative_to(root).as_posix()
        if where.startswith(NO_SIMD_FLOAT):
            item.add_marker(pytest.mark.no_simd_float)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the soaring kernels, or load them from numba's on-disk cache, before any test:
    no test (least of all a realtime one) pays a compile inside its loop, and later processes
    of the run load the cache instead of compiling again."""
    from sim_core.soaring import warm_up

    warm_up()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """``tests/data``: the seeds' data files and their code's outputs (see each README there)."""
    return DATA


@pytest.fixture(scope="session", autouse=True)
def _private_domain(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Domain]:
    """Every default bus, pty link and virtual CAN channel of the suite belongs to this run
    (hil_bridge.bus.domain), so the suite never meets a demo or another run on the machine."""
    with use(Domain.private(tmp_path_factory.mktemp("domain"))) as domain:
        yield domain


@pytest.fixture(autouse=True)
def _no_thread_leaks() -> Iterator[None]:
    """Fail a test that leaves a non-daemon thread of its own running (python-can's guard)."""
    before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + 2.0
    while True:
        leaked = [
            t for t in threading.enumerate()
            if t not in before and t.is_alive() and not t.daemon
        ]
        if not leaked or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    if leaked:
        pytest.fail(f"test leaked running threads: {[t.name for t in leaked]}")


@pytest.fixture(autouse=True)
def _no_worker_or_shared_memory_leaks() -> Iterator[None]:
    """Fail a test that leaves an echo worker or echo node process (``hil_bridge.server.echo_pool``,
    ``echo_nodes``) running or a shared tile store or pose ring (``hil_bridge.server.shared_tiles``)
    of this process behind."""
    import multiprocessing

    from hil_bridge.server.echo_nodes import NODE_NAME
    from hil_bridge.server.echo_pool import WORKER_NAME
    from hil_bridge.server.shared_tiles import stores_of

    yield
    deadline = time.monotonic() + 5.0
    while True:
        workers = [p for p in multiprocessing.active_children()
                   if p.name in (WORKER_NAME, NODE_NAME)]
        stores = stores_of(os.getpid())
        if not (workers or stores) or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    if workers or stores:
        for p in workers:
            p.kill()
        for store in stores:
            shutil.rmtree(store, ignore_errors=True)
        pytest.fail(f"test leaked echo workers {[p.pid for p in workers]} and/or shared tile "
                    f"stores {[str(s) for s in stores]}")
