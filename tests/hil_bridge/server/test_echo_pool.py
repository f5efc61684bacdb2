"""The echo service's process pool: the same echoes as one worker, tiles shared in memory,
deadlines that degrade or drop (and count it), nothing left behind."""

from __future__ import annotations

import dataclasses
import os
import queue
import signal
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.domain import Domain, shared_root
from hil_bridge.bus.messages import SonarPing
from hil_bridge.files.scene import load_scene
from hil_bridge.server.echo_compute import (
    PROBE_AFTER,
    DeadlinePlanner,
    EchoJob,
    EchoRequest,
    EchoResult,
    SonarPose,
    answer_echo,
    compute_echo,
)
from hil_bridge.server.echo_pool import WORKER_NAME
from hil_bridge.server.echo_service import EchoService
from hil_bridge.server.shared_tiles import SharedTiles, stores_of
from sim_core.pose import quat_from_euler
from sim_core.scene import Scene
from sim_core.sonar.cost import EchoCost
from tests.hil_bridge.server._killed import kill_server

SCENE: dict[str, Any] = {
    "forest": {"preset": "seed000-fig5d", "tile_size_m": 10.0, "query_radius_m": 4.0},
    "sonars": [
        {"id": 0, "mount": 1, "fidelity": "fast", "echo": {"samples": 8000}},
        {"id": 1, "mount": 1, "fidelity": "reference", "echo": {"samples": 8000}},
    ],
    "vehicles": [{"id": 1, "path": {"kind": "points", "points": [[2, 5, 2], [18, 5, 2]]}}],
}


def _requests(n: int, sonar: int, *, deadline: float | None = None) -> list[EchoRequest]:
    """Pings from poses spread over the Fig 5(d) forest, looking in many directions."""
    rng = np.random.default_rng(sonar)
    out = []
    for k in range(n):
        p = np.array([rng.uniform(2, 18), rng.uniform(2, 18), rng.uniform(1.5, 4.0)])
        q = quat_from_euler(rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(-3, 3))
        ping = SonarPing(stamp_ns=0, ping_seq=k, az=float(rng.uniform(-0.5, 0.5)),
                         el=float(rng.uniform(-0.3, 0.3)), beamwidth=float(rng.uniform(0.5, 1.1)),
                         sonar_id=sonar)
        out.append(EchoRequest(sonar, ping, SonarPose(0, p, q), time.monotonic(), deadline))
    return out


class _Sink:
    """Collects what an EchoService hands back."""

    def __init__(self) -> None:
        self.echoes: queue.Queue[tuple[EchoRequest, EchoResult]] = queue.Queue()
        self.errors: list[str] = []
        self.dropped: list[EchoRequest] = []

    def service(self, scene: Scene, **kw: Any) -> EchoService:
        return EchoService(scene, on_echo=lambda r, e: self.echoes.put((r, e)),
                           on_error=lambda r, m: self.errors.append(m),
                           on_drop=self.dropped.append, **kw)

    def take(self, n: int, timeout: float = 120.0) -> dict[tuple[int, int], EchoResult]:
        got = {}
        for _ in range(n):
            req, res = self.echoes.get(timeout=timeout)
            got[(req.sonar_id, req.ping.ping_seq)] = res
        return got


def _run(scene: Scene, requests: list[EchoRequest], **kw: Any) -> dict[tuple[int, int], Any]:
    sink = _Sink()
    svc = sink.service(scene, deadlines=False, queue_size=len(requests), **kw)
    svc.start()
    try:
        for req in requests:
            svc.submit(req)
        got = sink.take(len(requests))
    finally:
        svc.close()
    assert sink.errors == [] and sink.dropped == []
    return got


def test_the_pool_gives_the_echoes_of_one_worker_bit_for_bit() -> None:
    scene = load_scene(SCENE)
    requests = _requests(10, 0) + _requests(3, 1)
    pool = _run(scene, requests, worker="pool", workers=2)
    thread = _run(scene, requests, worker="thread")
    for req in requests:
        ping = req.ping
        direct = compute_echo(load_scene(SCENE), req.sonar_id, req.pose.position,
                              req.pose.orientation, ping.az, ping.el, ping.beamwidth)
        for got in (pool[(req.sonar_id, ping.ping_seq)], thread[(req.sonar_id, ping.ping_seq)]):
            np.testing.assert_array_equal(got.samples, direct.samples)
            np.testing.assert_array_equal(got.boresight, direct.boresight)
            assert (got.fidelity, got.leaves_in_beam, got.in_range, got.dropped) == (
                direct.fidelity, direct.leaves_in_beam, direct.in_range, direct.dropped)
            assert not got.degraded
    fidelities = {r.fidelity for r in pool.values()}
    assert fidelities == {"fast", "reference"}
    assert sum(r.leaves_in_beam > 0 for r in pool.values()) >= 5


def test_tiles_are_published_once_and_mapped_read_only(tmp_path: Path) -> None:
    scene = load_scene(SCENE)
    forest = scene.forest_source
    store = SharedTiles.create(Domain.private(tmp_path), forest.engine.names)
    try:
        built: list[tuple[tuple[int, int], int]] = []
        fetch = store.source(forest.build, built)
        first = fetch((0, 0))
        again = fetch((0, 0))
        assert [t for t, _ in built] == [(0, 0)] and store.published == 1
        direct = forest.build((0, 0))
        assert first.leaves == direct.leaves == again.leaves
        np.testing.assert_array_equal(first.tree_xy, direct.tree_xy)
        np.testing.assert_array_equal(first.tree_species, direct.tree_species)
        assert not first.leaves.centers.flags.writeable
        assert store.directory.parent == shared_root() / store.directory.parent.name
    finally:
        store.remove_all()
    assert not store.directory.exists()


def _deadline_service(sink: _Sink, cost: EchoCost, worker: str = "thread") -> EchoService:
    return sink.service(load_scene(SCENE), worker=worker, workers=1, deadlines=True, cost=cost)


def test_a_ping_superseded_by_its_sonars_next_ping_is_dropped_and_counted() -> None:
    sink = _Sink()
    svc = _deadline_service(sink, EchoCost())
    a, b = _requests(2, 0, deadline=time.monotonic() + 60.0)
    assert svc.submit(a) is True
    assert svc.submit(b) is False  # a's time was up when b (its sonar's next ping) came
    svc.start()
    try:
        got = sink.take(1)
    finally:
        svc.close()
    assert list(got) == [(0, 1)] and sink.dropped == [a]
    st = svc.stats()
    assert (st["requests"], st["expired"], st["answered"], st["dropped"]) == (2, 1, 1, 0)


def test_a_latency_budget_makes_an_echo_due_that_long_after_its_ping_arrived() -> None:
    """Both pings' sonars ping again only in a minute; with a 1 s budget the ping that waited
    longer than that is dropped as expired, the other answered."""
    sink = _Sink()
    svc = sink.service(load_scene(SCENE), worker="thread", deadlines=True, budget_s=1.0)
    far = time.monotonic() + 60.0
    stale = _requests(1, 1, deadline=far)[0]
    svc.submit(stale)
    time.sleep(1.1)  # its budget runs out before the service starts
    fresh = dataclasses.replace(_requests(1, 0, deadline=far)[0], received=time.monotonic())
    svc.submit(fresh)
    svc.start()
    try:
        got = sink.take(1)
    finally:
        svc.close()
    assert list(got) == [(0, 0)] and sink.dropped == [stale]
    st = svc.stats()
    assert (st["requests"], st["expired"], st["answered"]) == (2, 1, 1)
    with pytest.raises(ValueError, match="budget_s"):
        sink.service(load_scene(SCENE), budget_s=0.0)


@pytest.mark.parametrize("worker", ["thread", "pool"])
def test_an_echo_that_cannot_be_ready_in_time_is_degraded_or_dropped_and_counted(
    worker: str,
) -> None:
    sink = _Sink()
    # a cost model that predicts seconds per leaf: 'fast' never fits the time left (the pool's
    # workers plan with the model they were given)
    svc = _deadline_service(sink, EchoCost(per_examined_s=1.0), worker)
    now = time.monotonic()
    late = _requests(1, 0, deadline=now - 1.0)[0]  # its time is already up
    tight = dataclasses.replace(_requests(2, 0)[1], deadline=now + 30.0)
    svc.start()
    try:
        svc.submit(late)
        time.sleep(0.2)
        svc.submit(tight)
        got = sink.take(1)
    finally:
        svc.close()
    echo = got[(0, 1)]
    assert echo.degraded and echo.fidelity == "realtime" and np.isfinite(echo.error_bound)
    assert sink.dropped == [late]
    st = svc.stats()
    assert (st["expired"], st["degraded"], st["answered"]) == (1, 1, 1)


def test_one_slow_echo_does_not_stop_the_echoes_after_it() -> None:
    """The planner scales the cost model by the ratios its echoes measured: after a slow first
    echo (a cold process) every later one is predicted not to fit and given up, so nothing new
    is measured. After PROBE_AFTER echoes given up in a row it tries one on the model alone,
    and that echo's measurement brings the ratio back."""
    scene = load_scene(SCENE)
    planner = DeadlinePlanner()
    job = EchoJob(0, np.array([2.0, 5.0, 2.0]), quat_from_euler(0.0, 0.0, 0.0), 0.0, 0.0,
                  0.5, deadline=time.monotonic() + 0.25)
    planner.observe("fast", 1e-3, 10.0)  # ten thousand times the model's time
    for _ in range(PROBE_AFTER):
        assert answer_echo(scene, job, planner) is None
    assert planner.probing and planner.scale("fast") == 1.0
    probe = answer_echo(scene, dataclasses.replace(job, deadline=time.monotonic() + 0.25),
                        planner)
    assert probe is not None and not probe.degraded and not planner.probing
    assert planner.scale("fast") < 1e4  # the median of the outlier and the probe's ratio


def test_without_deadlines_each_sonar_keeps_its_own_bounded_queue() -> None:
    sink = _Sink()
    svc = sink.service(load_scene(SCENE), worker="thread", deadlines=False, queue_size=2)
    reqs = _requests(3, 0) + _requests(1, 1)
    results = [svc.submit(r) for r in reqs]
    assert results == [True, True, False, True]  # sonar 0's oldest made room for its third
    assert sink.dropped == [reqs[0]]
    svc.close()


#: how long the injected reference echo takes at least, s
SLOW_S = 0.8
#: when the ping after it is due, s after it arrives: less than SLOW_S, and far more than
#: planning it takes
DUE_S = 0.4


def _slow_reference(leaves: Any, beam: Any, params: Any, *, fidelity: str) -> Any:
    """:func:`sim_core.sonar.synthesize`, but a ``reference`` echo takes SLOW_S longer."""
    from sim_core.sonar import synthesize

    if fidelity == "reference":
        time.sleep(SLOW_S)
    return synthesize(leaves, beam, params, fidelity=fidelity)


@pytest.mark.parametrize("worker", ["thread", "pool"])
def test_after_a_slow_echo_the_next_is_degraded_by_the_measured_ratio_or_dropped(
    worker: str,
) -> None:
    """The planner's rule (DeadlinePlanner): an echo is predicted to take the cost model's
    time times the measured / predicted ratio of the worker's echoes, and is degraded to
    ``realtime`` within the time left when that does not fit. The injected reference echo
    takes SLOW_S: the first ping (no deadline yet) is answered at ``reference`` and teaches
    the worker the ratio, so the next, due DUE_S < SLOW_S after it arrives, is predicted not
    to fit and is degraded; a ping whose time is up before it starts is dropped. How long a
    real echo takes on this machine, however loaded, decides none of it."""
    sink = _Sink()
    svc = sink.service(load_scene(SCENE), worker=worker, workers=1, deadlines=True,
                       synthesize=_slow_reference)
    first, second, third = _requests(3, 1)
    svc.start()
    try:
        assert svc.wait_ready(60.0)
        svc.submit(first)
        slow = sink.take(1)[(1, 0)]
        now = time.monotonic()
        svc.submit(dataclasses.replace(second, received=now, deadline=now + DUE_S))
        degraded = sink.take(1)[(1, 1)]
        expired = dataclasses.replace(third, deadline=time.monotonic() - 1.0)
        svc.submit(expired)
        deadline = time.monotonic() + 30.0
        while svc.stats()["expired"] == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        svc.close()
    assert slow.fidelity == "reference" and not slow.degraded
    assert slow.compute_ns >= SLOW_S * 1e9
    assert degraded.degraded and degraded.fidelity == "realtime"
    assert np.isfinite(degraded.error_bound)
    assert sink.dropped == [expired] and sink.errors == []
    st = svc.stats()
    assert (st["requests"], st["answered"], st["degraded"], st["expired"]) == (3, 2, 1, 1)


def _leaks() -> tuple[list[Any], list[Path]]:
    import multiprocessing

    return ([p for p in multiprocessing.active_children() if p.name == WORKER_NAME],
            stores_of(os.getpid()))


def test_a_server_with_a_pool_leaves_no_worker_or_shared_memory_behind() -> None:
    from hil_bridge.server.sim_server import SimServer

    srv = SimServer("server", bus="mem://pool_leaks", scene={**SCENE, "clock": {"mode": "fast"}},
                    echo_worker="pool", echo_workers=2, stop_after_s=0.5)
    srv.start()
    try:
        # start() returned once the workers were up and the first tiles built
        workers, stores = _leaks()
        assert len(workers) == 2 and len(stores) == 1
        assert srv.stats()["echo_tiles_built"] >= 1
    finally:
        srv.stop()
    assert _leaks() == ([], [])


def test_the_tiles_the_sonars_reach_first_are_built_before_the_service_is_ready() -> None:
    region = ((10.0, 10.0, 2.0), 6.0)
    svc = EchoService(load_scene(SCENE), worker="pool", workers=2, on_echo=lambda r, e: None,
                      on_error=lambda r, m: None, lookahead=lambda: [region])
    svc.start()
    try:
        assert svc.wait_ready(60.0)
        st = svc.stats()
        pool = svc._pool
        first = list(pool.geometry.tiles_near(np.asarray(region[0]), region[1]))
    finally:
        svc.close()
    assert len(first) >= 4  # the ball straddles the corner of four 10 m tiles
    assert st["tiles_built"] == st["tiles_prefetched"] == len(first)


CRASH = textwrap.dedent("""
    import multiprocessing, os, sys, time
    from hil_bridge.bus.domain import Domain, use
    from hil_bridge.server.sim_server import SimServer
    from hil_bridge.server.shared_tiles import stores_of
    if __name__ == "__main__":
        with use(Domain.private(sys.argv[1])) as domain:
            srv = SimServer("server", bus="mem://crash", scene={scene!r}, echo_worker="pool",
                            echo_workers=2)
            srv.start()
            while len(multiprocessing.active_children()) < 2 or not stores_of(os.getpid()):
                time.sleep(0.05)
            print(domain.token, *[p.pid for p in multiprocessing.active_children()], flush=True)
            time.sleep(600)
""")


def test_workers_of_a_killed_server_exit_and_its_tiles_are_swept_by_the_next_run(
    tmp_path: Path,
) -> None:
    script = tmp_path / "crash.py"
    script.write_text(CRASH.format(scene={**SCENE, "clock": {"mode": "fast"}}))
    token, left = kill_server(script, tmp_path / "d")
    assert not left, "a worker outlived its killed server"
    stale = list((shared_root() / token).iterdir())
    assert len(stale) == 1  # the killed server could not remove its tiles ...
    store = SharedTiles.create(Domain(None, token, tmp_path / "d"), ["maple"])
    store.remove_all()
    assert not stale[0].exists()  # ... the next run in its domain did


def test_a_dead_worker_is_replaced_and_its_echo_reported() -> None:
    sink = _Sink()
    svc = sink.service(load_scene(SCENE), worker="pool", workers=1, deadlines=False)
    svc.start()
    try:
        first = _requests(1, 0)[0]
        svc.submit(first)
        sink.take(1)
        pool = svc._pool
        victim = pool._slots[0].proc
        os.kill(victim.pid, signal.SIGKILL)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and svc.stats()["worker_restarts"] == 0:
            time.sleep(0.02)
        svc.submit(dataclasses.replace(first, ping=dataclasses.replace(first.ping, ping_seq=5)))
        got = sink.take(1)
    finally:
        svc.close()
    assert list(got) == [(0, 5)]
    assert svc.stats()["worker_restarts"] == 1
    # replaced, but never silent: a failure of the service's owner (the server)
    assert svc.faults.failure() == f"echo worker {victim.pid}: exited (code -{int(signal.SIGKILL)})"


def test_points_and_ahead_of_time_tiles_come_from_the_pool() -> None:
    got: queue.Queue[tuple[Any, Any]] = queue.Queue()
    # every tile a worker builds is built ahead, one job each: those the lookahead wants, then
    # those of the points (10 m tiles of the 20 x 20 m forest: 0..2 each way), then the points
    # gathered from the shared tiles
    svc = EchoService(load_scene(SCENE), worker="pool", workers=1,
                      on_echo=lambda r, e: None, on_error=lambda r, m: None,
                      points=((((5.0, 5.0, 2.0), 4.0),), 500),
                      on_points=lambda c, r: got.put((c, r)),
                      lookahead=lambda: [((19.0, 19.0, 2.0), 0.1)])
    svc.start()
    try:
        centres, radii = got.get(timeout=60)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and svc.stats()["tiles_built"] < 9:
            time.sleep(0.05)
        st = svc.stats()
    finally:
        svc.close()
    assert centres.shape == (500, 3) and radii.shape == (500,)
    assert (st["tiles_built"], st["tiles_prefetched"]) == (9, 9)


def test_points_arrive_when_their_tiles_do_not_fit_the_tile_cache_together() -> None:
    """Each tile of the points is built ahead once; tiles the cache evicted again before the
    points job are rebuilt by that job, not re-queued for ever."""
    got: queue.Queue[tuple[Any, Any]] = queue.Queue()
    scene = load_scene({**SCENE, "forest": {**SCENE["forest"], "max_cache_bytes": 1}})
    svc = EchoService(scene, worker="thread", on_echo=lambda r, e: None,
                      on_error=lambda r, m: None,
                      points=((((5.0, 5.0, 2.0), 4.0), ((15.0, 15.0, 2.0), 4.0)), 10**6),
                      on_points=lambda c, r: got.put((c, r)))
    svc.start()
    try:
        centres, radii = got.get(timeout=60)
        st = svc.stats()
    finally:
        svc.close()
    full = load_scene(SCENE)
    tiles = {t for c in ((5.0, 5.0, 2.0), (15.0, 15.0, 2.0))
             for t in full.forest_source.tiles_near(np.asarray(c), 4.0)}
    assert st["tiles_prefetched"] == len(tiles) >= 2
    assert len(centres) == len(radii) == sum(len(full.forest_source.tile(t).radii) for t in tiles)
