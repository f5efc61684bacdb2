"""The ROS 2 side of ``bench/bench_ros2.py``: plain rclpy (no echoloop import), run as a process.

    python bench/ros2_peer.py receive OUT.npz --gliders 8 --sonars 8 --duration S
    python bench/ros2_peer.py dds-send --rate 250 --gliders 8 --duration S  # DDS alone
    python bench/ros2_peer.py dds-receive OUT.npz --duration S
    python bench/ros2_peer.py command OUT.npz --glider G --rate 20 --duration S

``receive`` subscribes ``/glider_<i>/odom`` and ``/sonar_<i>/echo`` and records, per message,
the glider or sonar, the header stamp and ``time.monotonic_ns()`` at the callback (the host's
monotonic clock, which the publisher in the benchmark's process shares). ``dds-*`` is rclpy to
rclpy, bursts of 8 Odometry 250 times a second as a server's ticks come, with the publisher's
monotonic time in the header. Receivers use rclpy's ``EventsExecutor`` (the executor rclpy
offers for high message rates). ``command`` publishes
``[bank, airspeed]`` on ``/glider_G/cmd`` with a bank unique to each command and records when.
Every mode stops at ``--duration`` (wall seconds) and writes OUT.npz.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import Image
from std_msgs.msg import Float64MultiArray


def _ns(stamp: object) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)  # type: ignore[attr-defined]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=["receive", "dds-send", "dds-receive", "command"])
    p.add_argument("out", nargs="?")
    p.add_argument("--gliders", type=int, default=8)
    p.add_argument("--sonars", type=int, default=8)
    p.add_argument("--glider", type=int, default=0)
    p.add_argument("--rate", type=float, default=20.0)
    p.add_argument("--duration", type=float, required=True)
    args = p.parse_args()
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bench_peer", context=context)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    rows: list[tuple[int, int, int]] = []
    end = time.monotonic() + args.duration
    if args.mode == "receive":
        for i in range(args.gliders):
            node.create_subscription(
                Odometry, f"/glider_{i}/odom",
                lambda m, i=i: rows.append((i, _ns(m.header.stamp), time.monotonic_ns())), 50)
        for i in range(args.sonars):
            node.create_subscription(
                Image, f"/sonar_{i}/echo",
                lambda m, i=i: rows.append((-1 - i, _ns(m.header.stamp), time.monotonic_ns())),
                10)
    elif args.mode == "dds-receive":
        node.create_subscription(
            Odometry, "/bench/odom",
            lambda m: rows.append((0, _ns(m.header.stamp), time.monotonic_ns())), 50)
    if args.mode in ("receive", "dds-receive"):
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    elif args.mode == "dds-send":  # bursts of --gliders messages at --rate, as a tick sends
        pub = node.create_publisher(Odometry, "/bench/odom", 50)
        msg = Odometry()
        period = 1.0 / args.rate
        due = time.monotonic() + 1.0  # discovery
        while due < end:
            time.sleep(max(0.0, due - time.monotonic()))
            for _ in range(args.gliders):
                now = time.monotonic_ns()
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
                pub.publish(msg)
            due += period
    else:
        pub = node.create_publisher(Float64MultiArray, f"/glider_{args.glider}/cmd", 10)
        period = 1.0 / args.rate
        due, k = time.monotonic() + 1.0, 0
        while due < end:
            executor.spin_once(timeout_sec=max(0.0, due - time.monotonic()))
            if time.monotonic() < due:
                continue
            k += 1
            bank = 0.1 + 1e-6 * k  # unique per command: the benchmark finds it on the bus
            rows.append((k, round(bank * 1e9), time.monotonic_ns()))
            pub.publish(Float64MultiArray(data=[bank, 10.0]))
            due += period
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()
    if args.out:
        np.save(args.out, np.array(rows, dtype=np.int64).reshape(-1, 3))


if __name__ == "__main__":
    main()
