"""A plain ROS 2 node (rclpy and the standard message packages, no echoloop import), run as a
process of its own by the bridge's tests: what a user's controller sees of the simulation.

    python rclpy_client.py OUT.npz --duration S [--glider G --bank B --airspeed V]
                           [--mismatched-qos]

It subscribes the default mapping's topics of glider 0 and sonar 0 with ``use_sim_time``, flies
glider G by publishing ``[bank, airspeed]`` on ``/glider_G/cmd`` every 50 ms, and writes what it
received to OUT.npz. ``--mismatched-qos`` also subscribes ``/glider_0/odom`` asking for
transient-local durability, which the bridge does not offer.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image
from std_msgs.msg import Float64MultiArray


def _ns(stamp: object) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)  # type: ignore[attr-defined]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("out")
    p.add_argument("--duration", type=float, required=True)
    p.add_argument("--glider", type=int, default=None)
    p.add_argument("--bank", type=float, default=0.0)
    p.add_argument("--airspeed", type=float, default=0.0)
    p.add_argument("--mismatched-qos", action="store_true")
    args = p.parse_args()

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("echoloop_test_client", context=context,
                             parameter_overrides=[Parameter("use_sim_time", value=True)])
    odom: list[tuple[int, float, float, float, float, float, float, float]] = []
    clock: list[int] = []
    sim_now: list[tuple[int, int]] = []
    echoes: list[tuple[int, np.ndarray]] = []
    echo_stamps: list[int] = []

    def on_odom(m: Odometry) -> None:
        q = m.pose.pose.orientation
        p_ = m.pose.pose.position
        odom.append((_ns(m.header.stamp), p_.x, p_.y, p_.z, q.w, q.x, q.y, q.z))

    def on_clock(m: Clock) -> None:
        clock.append(_ns(m.clock))

    def on_echo(m: Image) -> None:
        echo_stamps.append(_ns(m.header.stamp))
        if len(echoes) < 5:
            assert m.encoding == "32FC1"
            samples = np.frombuffer(bytes(m.data), dtype="<f4").reshape(m.height, m.width)
            echoes.append((_ns(m.header.stamp), samples.copy()))

    node.create_subscription(Odometry, "/glider_0/odom", on_odom, 50)
    node.create_subscription(Clock, "/clock", on_clock, 10)
    node.create_subscription(Image, "/sonar_0/echo", on_echo, 10)
    if args.mismatched_qos:
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Odometry, "/glider_0/odom", lambda m: None, latched)
    cmd = None
    if args.glider is not None:
        cmd = node.create_publisher(Float64MultiArray, f"/glider_{args.glider}/cmd", 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    end = time.monotonic() + args.duration
    next_cmd = 0.0
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)
        if clock:
            sim_now.append((clock[-1], node.get_clock().now().nanoseconds))
        if cmd is not None and time.monotonic() >= next_cmd:
            cmd.publish(Float64MultiArray(data=[args.bank, args.airspeed]))
            next_cmd = time.monotonic() + 0.05
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()
    np.savez(
        args.out,
        odom=np.array(odom, dtype=np.float64).reshape(-1, 8),
        odom_stamps=np.array([o[0] for o in odom], dtype=np.int64),
        clock=np.array(clock, dtype=np.int64),
        sim_now=np.array(sim_now, dtype=np.int64).reshape(-1, 2),
        echo_stamps=np.array([e[0] for e in echoes], dtype=np.int64),
        all_echo_stamps=np.array(echo_stamps, dtype=np.int64),
        **{f"echo_{i}": e[1] for i, e in enumerate(echoes)},
    )


if __name__ == "__main__":
    main()
