"""The floor of a Python bridge, for ``bench/bench_ros2.py``: the bus in, rclpy out, no conversion.

    python bench/ros2_floor.py --duration S --echo-shape 2 12000
        (ECHOLOOP_DOMAIN and ROS_DOMAIN_ID from the environment)

It takes the bridge's path with the conversion left out: the same bus subscriptions on two
receive threads (``/clock`` and ``/glider/`` on one, ``/sonar/`` on the other), the same
Fast DDS participant (UDP on the loopback interface, ``ros2_bridge.bridge.PROFILE``), the same
QoS (reliable, volatile, the default mapping's depths). Of a bus message it reads the topic and
the header, never the payload: each state becomes an ``Odometry`` on ``/glider_<id>/odom`` with
the state's stamp and fixed numbers, each echo an ``Image`` of ``--echo-shape`` samples on
``/sonar_<id>/echo``, each ``/clock`` a ``Clock``, all serialised as the bridge serialises them
(:mod:`ros2_bridge.cdr`). What the bridge does beyond this (decoding the payload, the frame
algebra, its bookkeeping) is what this floor leaves out: a Python bridge cannot be faster than
it on the same machine. It prints ``running`` on standard error once its publishers exist.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from typing import Any

import numpy as np

from hil_bridge.bus.codec import decode_header
from hil_bridge.bus.domain import current
from hil_bridge.bus.transport import open_transport
from ros2_bridge import cdr
from ros2_bridge.bridge import PROFILE

#: an Odometry's numbers: at the origin, level, at rest
ROW = np.zeros((1, cdr.ODOMETRY_DOUBLES))
ROW[0, 6] = 1.0


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--duration", type=float, required=True)
    p.add_argument("--echo-shape", type=int, nargs=2, required=True,
                   metavar=("CHANNELS", "SAMPLES"))
    args = p.parse_args()
    os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(PROFILE)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Image

    context = rclpy.Context()
    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"], context=context)
    node = rclpy.create_node("bench_floor", context=context, enable_rosout=False,
                             start_parameter_services=False)
    pubs: dict[bytes, Any] = {}

    def publisher(topic: bytes) -> Any:
        pub = pubs.get(topic)
        if pub is None:
            name = topic.rstrip(b"\0").decode()
            ident = name.split("/")[2] if name.count("/") >= 3 else ""
            kind, ros_topic, depth = {
                "/clock": (Clock, "/clock", 1), "/state": (Odometry, f"/glider_{ident}/odom", 10),
                "/echo": (Image, f"/sonar_{ident}/echo", 10)}[name[name.rfind("/"):]]
            pub = pubs[topic] = node.create_publisher(
                kind, ros_topic, QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE))
        return pub

    samples = np.zeros(args.echo_shape, dtype=np.float32)
    stop = threading.Event()

    def forward(prefixes: tuple[bytes, ...]) -> None:
        transport = open_transport(current().bus_url)
        for prefix in prefixes:
            transport.subscribe(prefix)
        try:
            while not stop.is_set():
                frames = transport.recv(timeout=0.1)
                if frames is None:
                    continue
                topic, stamp = frames[0], decode_header(frames[1]).stamp_ns
                if topic.endswith(b"/state\0"):
                    gid = topic.split(b"/")[2].decode()
                    data = cdr.odometry(stamp, "map", f"glider_{gid}", ROW[0])
                elif topic.endswith(b"/echo\0"):
                    data = cdr.image(stamp, f"sonar_{topic.split(b'/')[2].decode()}", samples)
                elif topic == b"/clock\0":
                    data = cdr.clock(stamp)
                else:
                    continue
                publisher(topic).publish(data)
        finally:
            transport.close()

    threads = [threading.Thread(target=forward, args=(prefixes,), daemon=True)
               for prefixes in ((b"/clock\0", b"/glider/"), (b"/sonar/",))]
    for t in threads:
        t.start()
    print("running", file=sys.stderr, flush=True)
    time.sleep(args.duration)
    stop.set()
    for t in threads:
        t.join()
    node.destroy_node()
    context.try_shutdown()


if __name__ == "__main__":
    main()
