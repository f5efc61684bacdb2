"""A 6-DoF vehicle flown into the ground is down, held at rest where it came down, and the run
goes on: the server neither fails nor publishes a non-finite state."""

from __future__ import annotations

import math
import threading
import time

from hil_bridge.bus.messages import GliderState, SurfaceCmd
from hil_bridge.bus.node import Node
from hil_bridge.bus.qos import COMMAND, QoSProfile
from hil_bridge.server.sim_server import SimServer

KEEP_ALL = QoSProfile("keep_all", depth=100_000)


def test_a_glider_banked_into_the_ground_is_held_down_and_the_run_goes_on() -> None:
    bus = "mem://sixdof_down?depth=100000"
    scene = {"state_rate_hz": 50.0, "clock": {"mode": "fast"}, "vehicles": [
        {"id": 7, "sixdof": {"airspeed_mps": 20.0},
         "path": {"kind": "points", "points": [[0.0, 0.0, 30.0], [500.0, 0.0, 30.0]]}},
        {"id": 8, "path": {"kind": "points", "points": [[0.0, 50.0, 30.0], [500.0, 50.0, 30.0]]}},
    ]}
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=30.0)
    obs = Node("observer", bus=bus)
    states: dict[int, list[GliderState]] = {7: [], 8: []}
    for gid, box in states.items():
        obs.create_subscription(GliderState, f"/glider/{gid}/state", box.append, KEEP_ALL)
    pub = obs.create_publisher(SurfaceCmd, "/glider/7/surfaces", qos=COMMAND)
    obs.start()
    done = threading.Event()

    def bank_hard() -> None:  # the first states may come before the first command: any time
        while not done.is_set():
            pub.publish(SurfaceCmd(stamp_ns=0, aileron=0.5, elevator=0.0, throttle=0.0,
                                   rudder=0.0, glider_id=7))
            time.sleep(0.002)

    t = threading.Thread(target=bank_hard, daemon=True)
    t.start()
    srv.start()
    try:
        assert srv.wait_done(timeout=300)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and len(states[8]) < 1501:
            time.sleep(0.05)
    finally:
        done.set()
        t.join()
        srv.stop()
        obs.stop()
    assert srv.failure(final=True) is None
    assert srv.stats()["vehicles_down"] == 1
    flown = states[7]
    assert len(flown) == len(states[8]) == 1501  # t = 0 .. 30 s at 20 ms: the run went on
    down = [s for s in flown if not s.alive]
    assert down and flown[-1] is down[-1] and 5.0 < down[0].stamp_ns / 1e9 < 28.0
    for s in flown:
        assert all(math.isfinite(v) for v in (s.x, s.y, s.z, s.vz, s.airspeed, s.roll, s.pitch))
    last = down[0]
    for s in down:  # held where it came down, at rest
        assert (s.x, s.y, s.z) == (last.x, last.y, last.z) and s.airspeed == 0.0
