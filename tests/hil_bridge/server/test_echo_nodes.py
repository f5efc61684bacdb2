"""Echo nodes (echo_worker: nodes): pings answered in processes of their own, on the bus, at the
poses the server shares with them in memory."""

from __future__ import annotations

import multiprocessing
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
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from hil_bridge.files.scene import load_scene
from hil_bridge.priority import can_raise
from hil_bridge.server.echo_compute import compute_echo
from hil_bridge.server.echo_nodes import NODE_NAME
from hil_bridge.server.echo_pool import WORKER_NAME, WORKER_NICE
from hil_bridge.server.emission import EmissionPoses
from hil_bridge.server.pose_history import PoseHistory
from hil_bridge.server.pose_ring import PoseRing
from hil_bridge.server.shared_tiles import stores_of
from hil_bridge.server.sim_server import SimServer
from sim_core.config import ConfigError
from sim_core.pose import pose_compose, quat_from_euler
from tests.hil_bridge.server._killed import kill_server

ECHO = {"samples": 8000}  # 20 ms at 400 kHz: leaves up to 3.4 m, keeps the test quick
TICK_NS = 50_000_000


def _scene() -> dict[str, Any]:
    return {
        "forest": {"preset": "seed000-fig5d", "query_radius_m": 4.0},
        "sonars": [{"id": 3, "mount": 100, "echo": ECHO},
                   {"id": 4, "mount": 101, "echo": ECHO, "mount_rpy_rad": [0.0, 0.2, 0.0]}],
        "vehicles": [
            {"id": 100, "path": {"kind": "points", "points": [[2.0, 5.0, 2.0], [18.0, 5.0, 2.0]]}},
            {"id": 101, "path": {"kind": "points", "points": [[4.0, 3.0, 2.5], [4.0, 17.0, 2.5]]}},
        ],
        "state_rate_hz": 1e9 / TICK_NS,
        "clock": {"mode": "fast"},
    }


def _nodes() -> list[Any]:
    return [p for p in multiprocessing.active_children() if p.name == NODE_NAME]


def _ticks(n: int, m: int, seed: int = 0) -> list[tuple[int, np.ndarray, ...]]:
    rng = np.random.default_rng(seed)
    return [(k * TICK_NS, rng.normal(size=(m, 3)), rng.normal(size=(m, 3)),
             rng.normal(size=(m, 4)), rng.normal(size=(m, 3))) for k in range(n)]


def test_a_ring_reader_keeps_the_writers_history_bit_for_bit(tmp_path: Path) -> None:
    ring = PoseRing.create(Domain.private(tmp_path), (7, 2), slots=8)
    try:
        reader = PoseRing.open(ring.path)
        assert reader.ids == (7, 2)
        theirs = PoseHistory(reader.ids, tick_ns=TICK_NS, history_s=1.0)
        ours = PoseHistory((2, 7), tick_ns=TICK_NS, history_s=1.0)
        for k, tick in enumerate(_ticks(5, 2)):
            ring.write(*tick)
            ours.record(tick[0], (7, 2), *tick[1:])
            if k % 2:
                reader.follow(theirs)
        assert reader.follow(theirs) == 1 and reader.follow(theirs) == 0
        assert theirs.recorded_ns == ours.recorded_ns == 4 * TICK_NS
        for vid in (7, 2):
            for t in (0, TICK_NS, 2 * TICK_NS + 12_345_678, 4 * TICK_NS):
                a, b = theirs.pose_at(vid, t), ours.pose_at(vid, t)
                for field in ("position", "orientation", "velocity", "rates"):
                    np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        # a reader that falls more than a ring behind counts the ticks it lost
        for tick in _ticks(11, 2, seed=1):
            ring.write(tick[0] + 5 * TICK_NS, *tick[1:])
        # of the last 8 ticks, the oldest's slot is the one the writer fills next
        assert reader.follow(theirs) == 7 and reader.missed == 4
        assert theirs.recorded_ns == 15 * TICK_NS
    finally:
        ring.remove()
    assert not ring.path.exists()


def test_a_node_reads_the_ring_when_a_ping_comes_and_while_it_waits_not_every_tick(
        tmp_path: Path) -> None:
    """A node's emission poses refresh its history from the ring: before a ping is placed (a
    tick in the ring but not yet read answers it at once), and every refresh_s while a ping
    waits for its tick (written after the ping came, read with no one else polling)."""
    ring = PoseRing.create(Domain.private(tmp_path), (7,), slots=64)
    reader = PoseRing.open(ring.path)
    history = PoseHistory(reader.ids, tick_ns=TICK_NS, history_s=1.0)
    reads: list[int] = []

    def refresh() -> None:
        reads.append(reader.follow(history))

    got: queue.Queue[tuple[Any, Any]] = queue.Queue()
    poses = EmissionPoses(history, horizon_ns=4 * TICK_NS, wait_s=600.0,
                          on_pose=lambda payload, pose, _t: got.put((payload, pose)),
                          refresh=refresh, refresh_s=0.002)
    poses.start(Faults("node"))
    ticks = _ticks(6, 1)
    try:
        for tick in ticks[:3]:
            ring.write(*tick)
        poses.request(7, 2 * TICK_NS, "in the ring", time.monotonic())
        payload, pose = got.get_nowait()  # read on request: answered at once, not held
        assert payload == "in the ring" and pose.source == "history" and reads == [3]
        poses.request(7, 4 * TICK_NS + 5, "ahead", time.monotonic())
        assert got.empty() and poses.stats()["pings_waiting_tick"] == 1
        for tick in ticks[3:]:
            ring.write(*tick)  # only the waiting ping's refreshes read these
        payload, pose = got.get(timeout=30)
        assert payload == "ahead" and (pose.t_ns, pose.source) == (4 * TICK_NS + 5, "history")
        assert sum(reads) == 6 and history.recorded_ns == 5 * TICK_NS
        waited = len(reads)
        time.sleep(0.05)  # nothing held: nothing polls the ring
        assert len(reads) == waited
    finally:
        poses.close()
        ring.remove()
    with pytest.raises(ValueError, match="refresh_s"):
        EmissionPoses(history, horizon_ns=0, wait_s=0.0, on_pose=print, refresh_s=0.0)


def test_echo_nodes_answer_on_the_bus_as_the_servers_own_thread_would(tmp_path: Path) -> None:
    bus = f"ipc://{tmp_path}/bus"
    srv = SimServer("server", bus=bus, scene=_scene(), stop_after_s=0.1, echo_worker="nodes",
                    echo_workers=2)
    head = Node("head", bus=bus)
    pubs = {i: head.create_publisher(SonarPing, f"/sonar/{i}/ping") for i in (3, 4)}
    echoes: queue.Queue[SonarEcho] = queue.Queue()
    for i in (3, 4):
        head.create_subscription(SonarEcho, f"/sonar/{i}/echo", echoes.put)
    srv.start()
    head.start()
    try:
        nodes = _nodes()
        assert len(nodes) == 2  # one per sonar: started, each on the bus, before the first tick
        # a fast clock raises no tick thread: the nodes yield to the server's process
        own = os.getpriority(os.PRIO_PROCESS, 0)
        assert [os.getpriority(os.PRIO_PROCESS, p.pid) for p in nodes] == [
            min(own + WORKER_NICE, 19)] * 2
        assert len(stores_of(os.getpid())) == 1  # the pose ring
        assert srv.wait_done(timeout=30)
        assert head.transport.sync(10.0)
        # emitted at the tick of 0.05 s, which both nodes have from the ring
        for i, seq in ((3, 7), (4, 8)):
            pubs[i].publish(SonarPing(stamp_ns=TICK_NS, ping_seq=seq, az=0.3, el=0.1,
                                      beamwidth=0.6))
        got = {e.sonar_id: e for e in (echoes.get(timeout=30), echoes.get(timeout=30))}
        deadline = time.monotonic() + 10
        while srv.stats()["echoes_published"] < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        stats = srv.stats()
    finally:
        srv.stop()
        head.stop()
    assert srv.failure() is None
    assert (stats["echo_worker"], stats["echo_workers"]) == ("nodes", 2)
    assert (stats["pings_received"], stats["echoes_published"]) == (2, 2)
    scene = load_scene(_scene())
    for sonar, echo in got.items():
        spec = next(s for s in scene.spec.sonars if s.id == sonar)
        pose = srv.fleet.history.pose_at(spec.mount, TICK_NS)  # the server's own history
        position, orientation = pose_compose(
            pose.position, pose.orientation, np.asarray(spec.mount_offset_m, dtype=np.float64),
            quat_from_euler(*spec.mount_rpy_rad))
        direct = compute_echo(scene, sonar, position, orientation, 0.3, 0.1, 0.6)
        assert echo.emit_ns == TICK_NS
        np.testing.assert_array_equal(echo.samples, direct.samples.astype(echo.samples.dtype))
        np.testing.assert_array_equal(echo.position, position.astype(echo.position.dtype))
        assert echo.leaves_in_beam == direct.leaves_in_beam > 0
    assert _nodes() == [] and stores_of(os.getpid()) == []


@pytest.mark.processes  # lifecycle: no float result to check without AVX-512
@pytest.mark.parametrize("worker", ["nodes", "pool"])
def test_echo_nodes_compete_as_equals_when_the_tick_thread_is_raised(
    worker: str, tmp_path: Path
) -> None:
    scene = {**_scene(), "clock": {"mode": "realtime"}}
    srv = SimServer("server", bus=f"ipc://{tmp_path}/bus", scene=scene, echo_worker=worker,
                    echo_workers=2, tick_nice=-3)
    raised = can_raise(-3)
    srv.start()
    try:
        procs = [p for p in multiprocessing.active_children()
                 if p.name in (NODE_NAME, WORKER_NAME)]
        nice = [os.getpriority(os.PRIO_PROCESS, p.pid) for p in procs]
        stats = srv.stats()
    finally:
        srv.stop()
    own = os.getpriority(os.PRIO_PROCESS, 0)
    # a pool keeps yielding: its scheduler thread shares the tick loop's interpreter
    expected = own if raised and worker == "nodes" else min(own + WORKER_NICE, 19)
    assert nice == [expected] * 2
    assert stats["echo_worker_nice"] == (0 if raised and worker == "nodes" else WORKER_NICE)


@pytest.mark.processes  # lifecycle: no float result to check without AVX-512
def test_an_echo_node_killed_fails_the_server_naming_it(tmp_path: Path) -> None:
    srv = SimServer("server", bus=f"ipc://{tmp_path}/bus", scene=_scene(), stop_after_s=600.0,
                    echo_worker="nodes", echo_workers=2)
    srv.start()
    try:
        victim = _nodes()[0]
        os.kill(victim.pid, signal.SIGKILL)
        deadline = time.monotonic() + 20
        while srv.failure() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        failure = srv.failure()
    finally:
        srv.stop()
    assert failure is not None and "echo node of sonars" in failure
    assert f"(pid {victim.pid})" in failure and f"exited (code -{int(signal.SIGKILL)})" in failure


@pytest.mark.processes
@pytest.mark.parametrize("scene", [{"clock": {"mode": "lockstep"}}, {}], ids=["lockstep", "mem"])
def test_nodes_are_refused_where_they_cannot_serve(scene: dict[str, Any], tmp_path: Path) -> None:
    bus = "mem://nodes_refused" if not scene else f"ipc://{tmp_path}/bus"
    srv = SimServer("server", bus=bus, scene={**_scene(), **scene}, echo_worker="nodes")
    try:
        with pytest.raises(ConfigError, match="echo_worker: nodes needs"):
            srv.start()
    finally:
        srv.stop()


CRASH = textwrap.dedent("""
    import multiprocessing, os, sys, time
    from hil_bridge.bus.domain import Domain, use
    from hil_bridge.server.sim_server import SimServer
    if __name__ == "__main__":
        with use(Domain.private(sys.argv[1])) as domain:
            srv = SimServer("server", bus="ipc://" + sys.argv[1] + "/bus", scene={scene!r},
                            echo_worker="nodes", echo_workers=2)
            srv.start()
            print(domain.token, *[p.pid for p in multiprocessing.active_children()
                                  if p.name == {name!r}], flush=True)
            time.sleep(600)
""")


@pytest.mark.processes  # lifecycle: no float result to check without AVX-512
def test_nodes_of_a_killed_server_exit_and_its_ring_is_swept_by_the_next_run(
    tmp_path: Path,
) -> None:
    script = tmp_path / "crash.py"
    script.write_text(CRASH.format(scene={**_scene(), "clock": {"mode": "realtime"}},
                                   name=NODE_NAME))
    (tmp_path / "d").mkdir()
    token, left = kill_server(script, tmp_path / "d")
    assert not left, "an echo node outlived its killed server"
    stale = list((shared_root() / token).iterdir())
    assert [s.name.split("-")[0] for s in stale] == ["poses"]  # the killed server's ring ...
    ring = PoseRing.create(Domain(None, token, tmp_path / "d"), (1,))
    ring.remove()
    assert not stale[0].exists()  # ... swept by the next run in its domain
