"""Recording determinism: the same scene and seed record the same content; another seed not.

What a recording holds beyond the simulation (receive times, publisher ids, wall-clock
``pub_ns``, ``/diagnostics`` counters) is left out; every topic's sequence of (seq, stamp,
type, frame id, payload bytes) is compared.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hil_bridge.launch.runner import run
from hil_bridge.recording.bag import bag_info, read_bag


def _launch(seed: int) -> dict[str, Any]:
    scene = {
        "seed": seed, "state_rate_hz": 20, "clock": {"mode": "fast"},
        "swarm": {"overrides": {"numAgents": 4, "dt": 0.1}},
        "forest": {"preset": "single-maple", "tiled": False},
        "sonars": [{"id": 0, "mount": 100}],
        "vehicles": [{"id": 100, "path": {"kind": "points", "speed_mps": 2.0,
                                          "points": [[-6.0, 0.0, 4.0], [6.0, 0.0, 4.0]]}}],
    }
    return {"nodes": [{"name": "server", "entry": "hil_bridge.server:SimServer",
                       "params": {"scene": scene, "stop_after_s": 3.0,
                                  "forest_points": 2000}}]}


def _content(path: Path) -> dict[str, list[tuple[Any, ...]]]:
    info = bag_info(path)
    assert not info.truncated and all(st.lost == 0 for st in info.topics.values())
    out: dict[str, list[tuple[Any, ...]]] = {}
    for m in read_bag(path):
        if m.topic != "/diagnostics":
            h = m.header
            out.setdefault(m.topic, []).append((h.seq, h.stamp_ns, h.type, h.frame_id, m.payload))
    return out


def test_same_seed_same_recording_other_seed_another(tmp_path: Path) -> None:
    recordings = {}
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        mcap = tmp_path / f"{name}.mcap"
        summary = run(_launch(seed), duration=2.0, record=mcap, handle_signals=False)
        assert summary.nodes["server"]["sim_time_s"] == 3.0
        recordings[name] = _content(mcap)
    a, b, c = recordings["a"], recordings["b"], recordings["c"]
    topics = {"/clock", "/thermals", "/forest/points", "/glider/0/state", "/glider/100/state"}
    assert topics <= set(a)
    assert len(a["/glider/0/state"]) == 61
    assert a == b
    assert a["/clock"] == c["/clock"]  # the same ticks ...
    for topic in ("/glider/0/state", "/thermals", "/forest/points"):
        assert a[topic] != c[topic], topic  # ... of another world
