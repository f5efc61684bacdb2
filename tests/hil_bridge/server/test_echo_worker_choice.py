"""echo_worker: auto (the default) picks the echo workers a scene needs and says which."""

from __future__ import annotations

import pytest

from hil_bridge.server.sim_server import SimServer
from hil_bridge.server.sonars import choose_worker
from sim_core.config import ConfigError


@pytest.mark.parametrize(("asked", "sonars", "cores", "chosen"), [
    ("auto", 1, 2, "thread"),   # one sonar's echoes never overlap
    ("auto", 2, 2, "nodes"),    # several sonars: side by side on the cores, off the server
    ("auto", 8, 1, "thread"),   # one core: a pool would only add start-up
    ("auto", 0, 8, "thread"),
    ("thread", 8, 8, "thread"),  # an explicit choice stands
    ("pool", 1, 1, "pool"),
    ("process", 1, 2, "process"),
    ("nodes", 1, 1, "nodes"),
])
def test_auto_chooses_by_sonars_and_cores(asked: str, sonars: int, cores: int,
                                          chosen: str) -> None:
    assert choose_worker(asked, sonars, cores) == chosen


def test_where_nodes_cannot_serve_auto_takes_a_pool_and_nodes_are_refused() -> None:
    assert choose_worker("auto", 8, 2, nodes_ok=False) == "pool"
    with pytest.raises(ConfigError, match="echo_worker: nodes needs a realtime or fast clock"):
        choose_worker("nodes", 8, 2, nodes_ok=False)
    with pytest.raises(ConfigError, match="echo_worker: expected auto, thread, process, pool "
                                          "or nodes, got 'gpu'"):
        choose_worker("gpu", 8, 2)


def test_the_server_says_what_it_chose() -> None:
    scene = {"forest": {"preset": "seed000-fig5d", "tiled": True, "tile_size_m": 10.0},
             "clock": {"mode": "fast"},
             "sonars": [{"id": 0, "mount": 1}],
             "vehicles": [{"id": 1, "path": {"kind": "points",
                                             "points": [[2, 5, 2], [18, 5, 2]]}}]}
    server = SimServer("server", bus="mem://echo_worker_choice", scene=scene, stop_after_s=0.1)
    try:
        server.start()
        assert server.wait_done(60)
        assert server.stats()["echo_worker"] == "thread"
    finally:
        server.stop()
