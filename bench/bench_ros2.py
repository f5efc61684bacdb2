"""The ROS 2 bridge under load, every party a process of its own in a free domain.

**States and echoes.** This benchmark's process publishes on the bus (run alone by
``echoloop bus``) what an 8-sonar scene's server publishes: ``/clock`` and the states of 8
gliders at 250 Hz, and the echoes of 8 sonars at 20 Hz each (2 channels x 12,000 float32
samples, 96 kB). The bridge (``echoloop ros2 bridge``, default mapping) turns them into
Odometry and Image messages, and a plain rclpy process (``bench/ros2_peer.py receive``)
subscribes to all 16 topics. Latency is echoloop publish (``time.monotonic_ns()`` just before
``Publisher.publish`` here) to the rclpy callback (the same host clock there), per state,
joined by glider and stamp. The first seconds (discovery) are left out. The bridge's CPU is
``utime + stime`` of its process over the window. Where the time goes, from the bridge's own
summary (its last 20,000 states): *the bus* is echoloop publish → received by the bridge
(``state_bus_ms``), *the bus + the bridge* → its Odometry handed to DDS (``state_out_ms``); the
rest of the latency is DDS's, which the first row measures alone. The last column is the stall
probe beside each row (``bench._util.StallProbe``: a thread at ``SCHED_FIFO`` 95 waking every
1 ms): wake-ups more than 3 ms late, and the latest, stalls of the platform itself.

**Baseline, same run.** DDS alone: rclpy to rclpy (``ros2_peer.py dds-send``: 8 Odometry per
tick at 250 Hz, to ``dds-receive``), with the sender's monotonic time in the header. And the
same echoloop path carrying one glider's states alone (no echoes): the path's floor when the
bridge has a single message a tick to write. And the floor of any bridge written in Python on
this machine: ``bench/ros2_floor.py`` in the bridge's place, under the same load, with the
bridge's bus subscriptions, receive threads, Fast DDS participant and QoS, forwarding each
message with its stamp read from the bus header alone (fixed Odometry numbers, no payload
decoded, no frame algebra): what is left of the latency and the CPU is the bus, rclpy, DDS and
the machine's two cores shared by four busy processes.

**Commands.** ``echoloop launch`` runs the server (8 swarm gliders, states at 250 Hz, realtime)
and the bridge. ``ros2_peer.py command`` flies glider 3 at 20 Hz, each command with a bank
unique to it. This process finds each command on the bus (``/glider/3/cmd``) and times ROS 2
publish to bus arrival. The server's ``cmd_apply_ms`` times each command's arrival to the
publish of the first state that flies it (``cmd_effect_ticks``: that state's tick, 1 = the
next). The sum of the two p99s, in state periods, bounds the p99 of ROS 2 publish → applied.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench._util import StallProbe, table
from hil_bridge.bus.domain import Domain, claim_first_free

TITLE = "ROS 2 bridge: 8 gliders at 250 Hz and 8 sonars' echoes to rclpy, commands back"

ROOT = Path(__file__).resolve().parent.parent
PEER = Path(__file__).with_name("ros2_peer.py")
FLOOR = Path(__file__).with_name("ros2_floor.py")
GLIDERS, SONARS = 8, 8
STATE_HZ, ECHO_HZ = 250, 20
ECHO_SHAPE = (2, 12_000)
WARM_S, RUN_S = 4.0, 20.0
CMD_GLIDER, CMD_HZ = 3, 20.0
#: the path's floor: one glider's states alone, no echoes (s)
SINGLE_S = 10.0


def _env(dom: Domain, ros_domain: int) -> dict[str, str]:
    env = dict(os.environ, ECHOLOOP_DOMAIN=str(dom.number), ROS_DOMAIN_ID=str(ros_domain),
               FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1")
    for name in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTDDS_DEFAULT_PROFILES_FILE"):
        env.pop(name, None)
    return env


def _cli(env: dict[str, str], *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "hil_bridge.cli", *args], cwd=ROOT, env=env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _peer(env: dict[str, str], *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, str(PEER), *args], cwd=ROOT, env=env, text=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_others(bus: subprocess.Popen[str], peer: subprocess.Popen[str]) -> dict[str, float]:
    """CPU seconds so far of the other parties: the bus proxy, the rclpy peer, this process."""
    return {"bus proxy": _cpu_s(bus.pid), "rclpy peer": _cpu_s(peer.pid),
            "this publisher": time.process_time()}


def _wait_for(proc: subprocess.Popen[str], text: str, timeout: float = 60.0) -> None:
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if text in line:
            return
        if not line and proc.poll() is not None:
            break
    raise RuntimeError(f"no {text!r} from {proc.args}")


def _stop(*procs: subprocess.Popen[str]) -> list[str]:
    """Stop ``procs`` (SIGTERM, then SIGKILL after 60 s); their standard outputs."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    outs = []
    for p in procs:
        try:
            out, _ = p.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            p.kill()
            out, _ = p.communicate()
        outs.append(out or "")
    return outs


def _pct(ms: np.ndarray, q: float) -> float:
    return float(np.percentile(ms, q)) if ms.size else math.nan


def _baseline(env: dict[str, str], tmp: Path) -> np.ndarray:
    out = tmp / "dds.npy"
    recv = _peer(env, "dds-receive", str(out), "--duration", "12")
    send = _peer(env, "dds-send", "--rate", str(STATE_HZ), "--gliders", str(GLIDERS),
                 "--duration", "10")
    _stop_when_done(send, recv)
    rows = np.load(out)
    rows = rows[rows[:, 1] > rows[:, 1].min() + 2_000_000_000]  # after discovery
    return (rows[:, 2] - rows[:, 1]) / 1e6


def _stop_when_done(*procs: subprocess.Popen[str]) -> None:
    for p in procs:
        _, err = p.communicate(timeout=120)
        if p.returncode != 0:
            raise RuntimeError(f"{p.args} exited {p.returncode}: {err[-2000:]}")


def _states_and_echoes(dom: Domain, env: dict[str, str], tmp: Path, *, gliders: int = GLIDERS,
                       sonars: int = SONARS, run_s: float = RUN_S,
                       floor: bool = False) -> dict[str, Any]:
    """One row: ``gliders`` states at :data:`STATE_HZ` and ``sonars`` echoes at :data:`ECHO_HZ`
    through the bridge (``floor``: through ``bench/ros2_floor.py`` instead) to the rclpy peer."""
    from hil_bridge.bus.messages import Clock, GliderState, SonarEcho
    from hil_bridge.bus.node import Node
    from sim_core.pose import quat_from_euler

    out = tmp / "recv.npy"
    bus = _cli(env, "bus", "--domain", str(dom.number))
    if floor:
        bridge = subprocess.Popen(
            [sys.executable, str(FLOOR), "--duration", str(WARM_S + run_s + 2),
             "--echo-shape", *map(str, ECHO_SHAPE)], cwd=ROOT,
            env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    else:
        bridge = _cli(env, "ros2", "bridge", "--domain", str(dom.number), "--json")
    peer = _peer(env, "receive", str(out), "--duration", str(WARM_S + run_s + 3), "--gliders",
                 str(gliders), "--sonars", str(sonars))
    node = Node("bench_sim", bus=dom.bus_url, diagnostics_period_s=0)
    clock_pub = node.create_publisher(Clock, "/clock")
    state_pubs = [node.create_publisher(GliderState, f"/glider/{i}/state")
                  for i in range(gliders)]
    echo_pubs = [node.create_publisher(SonarEcho, f"/sonar/{j}/echo") for j in range(sonars)]
    samples = np.random.default_rng(0).standard_normal(ECHO_SHAPE).astype(np.float32)
    sent: dict[tuple[int, int], int] = {}
    window = (int(WARM_S * 1e9), int((WARM_S + run_s) * 1e9))
    period_ns = 1_000_000_000 // STATE_HZ
    echo_every = STATE_HZ / ECHO_HZ
    try:
        _wait_for(bridge, "running")
        t0 = time.monotonic()
        cpu0 = cpu1 = math.nan
        cpu0_others = cpu1_others = {}
        for k in range(int((WARM_S + run_s) * STATE_HZ)):
            time.sleep(max(0.0, t0 + k / STATE_HZ - time.monotonic()))
            stamp = k * period_ns
            if stamp == window[0]:
                cpu0, cpu0_others = _cpu_s(bridge.pid), _cpu_others(bus, peer)
            clock_pub.publish(Clock(stamp_ns=stamp))
            headings = 0.3 * np.arange(gliders) + 0.2 * stamp * 1e-9
            quats = quat_from_euler(np.full(gliders, -0.2), np.full(gliders, 0.05), headings)
            for i, pub in enumerate(state_pubs):
                heading, q = float(headings[i]), quats[i]
                msg = GliderState(stamp_ns=stamp, x=10.0 * i, y=5.0 + stamp * 1e-9,
                                  z=40.0, heading=heading, bank=0.2, airspeed=10.0, vz=-0.6,
                                  glider_id=i, step=k, roll=-0.2, pitch=0.05, yaw=heading,
                                  qw=q[0], qx=q[1], qy=q[2], qz=q[3], roll_rate=0.0,
                                  pitch_rate=0.0, yaw_rate=0.2)
                sent[(i, stamp)] = time.monotonic_ns()
                pub.publish(msg)
            for j, pub in enumerate(echo_pubs):
                if math.floor((k + 1 - j * echo_every / sonars) / echo_every) > math.floor(
                        (k - j * echo_every / sonars) / echo_every):
                    pub.publish(SonarEcho(
                        stamp_ns=stamp, ping_seq=k, fs=400_000.0, samples=samples,
                        leaves_in_beam=1000, fidelity="fast", sonar_id=j, emit_ns=stamp,
                        position=np.array([1.0, 2.0, 3.0]),
                        orientation=np.array([1.0, 0.0, 0.0, 0.0]),
                        boresight=np.array([1.0, 0.0, 0.0])))
        cpu1 = _cpu_s(bridge.pid)
        cpu1_others = _cpu_others(bus, peer)
        _stop_when_done(peer)
    finally:
        node.stop()
        summaries = _stop(bridge, bus)
    stages = ({"state_bus_ms": None, "state_out_ms": None} if floor
              else json.loads(summaries[0])["nodes"]["ros2_bridge"])
    rows = np.load(out)
    states = rows[rows[:, 0] >= 0]
    echoes = rows[rows[:, 0] < 0]
    lat = []
    for gid, stamp, recv in states:
        if window[0] <= stamp < window[1]:
            lat.append((recv - sent[(int(gid), int(stamp))]) / 1e6)
    expected = gliders * int(run_s * STATE_HZ)
    in_window = echoes[(echoes[:, 1] >= window[0]) & (echoes[:, 1] < window[1])]
    return {"lat": np.array(lat), "expected": expected, "echoes": len(in_window),
            "echoes_expected": int(sonars * ECHO_HZ * run_s),
            "cpu_share": (cpu1 - cpu0) / run_s,
            "bus_ms": stages["state_bus_ms"], "out_ms": stages["state_out_ms"],
            "others": {k: (cpu1_others[k] - cpu0_others[k]) / run_s for k in cpu1_others}}


def _commands(dom: Domain, env: dict[str, str], tmp: Path) -> dict[str, Any]:
    from hil_bridge.bus.messages import GliderCmd
    from hil_bridge.bus.node import Node

    launch = {"nodes": [
        {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {"scene": {
            "state_rate_hz": STATE_HZ, "clock": {"mode": "realtime", "rate": 1.0},
            "swarm": {"law": "default", "seed": 2, "overrides": {"numAgents": GLIDERS}}}}},
        {"name": "ros2", "entry": "ros2_bridge.bridge:Ros2Bridge"},
    ]}
    path = tmp / "commands.yaml"
    path.write_text(yaml.safe_dump(launch))
    out = tmp / "cmd.npy"
    proc = _cli(env, "launch", str(path), "--domain", str(dom.number), "--json")
    arrived: dict[int, int] = {}
    node = Node("bench_tap", bus=dom.bus_url, diagnostics_period_s=0)
    node.create_subscription(
        GliderCmd, f"/glider/{CMD_GLIDER}/cmd",
        lambda m: arrived.setdefault(round(m.bank_cmd * 1e9), time.monotonic_ns()))
    node.start()
    try:
        _wait_for(proc, "echoloop launch: running")
        peer = _peer(env, "command", str(out), "--glider", str(CMD_GLIDER), "--rate",
                     str(CMD_HZ), "--duration", str(RUN_S))
        _stop_when_done(peer)
    finally:
        node.stop()
        proc.send_signal(signal.SIGTERM)
        stdout, _ = proc.communicate(timeout=120)
    summary = json.loads(stdout)
    rows = np.load(out)
    delays = np.array([(arrived[int(b)] - t) / 1e6 for _, b, t in rows if int(b) in arrived])
    return {"delays": delays, "sent": len(rows), "server": summary["nodes"]["server"],
            "bridge": summary["nodes"]["ros2"]}


def _costs() -> list[list[str]]:
    """Per-message costs in this process (median of 7 timings), no DDS: the bridge's work on a
    state (decode, the batch's frame algebra, the Odometry's CDR) and on an echo, each beside
    the rclpy path it replaced (fill an rclpy message, ``serialize_message``), timed here."""
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float32MultiArray

    from bench._util import median, time_it
    from hil_bridge.bus.codec import decode, encode
    from hil_bridge.bus.messages import GliderState, SonarEcho
    from ros2_bridge import cdr
    from ros2_bridge.convert import Converter
    from sim_core.pose import quat_from_euler

    conv = Converter()
    q = quat_from_euler(-0.2, 0.05, 0.3)
    frames = [encode(f"/glider/{i}/state", GliderState(
        stamp_ns=4_000_000, x=1.0, y=2.0, z=40.0, heading=0.3, bank=0.2, airspeed=10.0, vz=-0.6,
        glider_id=i, qw=q[0], qx=q[1], qy=q[2], qz=q[3], roll_rate=0.0, pitch_rate=0.0,
        yaw_rate=0.2), seq=0, pub_ns=0) for i in range(GLIDERS)]

    def tick() -> Any:
        states = [decode(f).msg for f in frames]
        conv.prepare(states)
        return [conv.convert("nav_msgs/msg/Odometry", str(i), st, f"/glider_{i}/odom")
                for i, st in enumerate(states)]

    def rclpy_odometry(data: bytes) -> Any:
        """The rclpy path: fill an Odometry from the same numbers, then serialise it."""
        odom = Odometry()
        odom.header.stamp.sec, odom.header.stamp.nanosec = 0, 4_000_000
        odom.header.frame_id, odom.child_frame_id = "map", "glider_0"
        row = np.frombuffer(data[-8 * cdr.ODOMETRY_DOUBLES:], dtype="<f8")
        pose, twist = odom.pose.pose, odom.twist.twist
        (pose.position.x, pose.position.y, pose.position.z, pose.orientation.x,
         pose.orientation.y, pose.orientation.z, pose.orientation.w) = (float(v) for v in row[:7])
        twist.linear.x, twist.linear.y, twist.linear.z = (float(v) for v in row[43:46])
        twist.angular.x, twist.angular.y, twist.angular.z = (float(v) for v in row[46:49])
        return serialize_message(odom)

    odom = tick()[0]
    row = np.frombuffer(odom[-8 * cdr.ODOMETRY_DOUBLES:], dtype="<f8").copy()
    samples = np.random.default_rng(0).standard_normal(ECHO_SHAPE).astype(np.float32)
    echo = SonarEcho(stamp_ns=1, ping_seq=0, fs=400_000.0, samples=samples, leaves_in_beam=0,
                     fidelity="fast", emit_ns=1)

    def rclpy_image() -> Any:
        image = Image(height=samples.shape[0], width=samples.shape[1], encoding="32FC1",
                      is_bigendian=0, step=4 * samples.shape[1])
        image.header.stamp.nanosec, image.header.frame_id = 1, "sonar_0"
        image.data = samples.tobytes()
        return serialize_message(image)

    array = Float32MultiArray()
    array.data = samples.ravel().tolist()

    def us(fn: Any, n: int) -> str:
        return f"{1e6 * median(time_it(lambda: [fn() for _ in range(n)], repeat=7)) / n:.1f}"

    per_state = float(us(tick, 50)) / GLIDERS
    return [
        ["bus: decode a state", us(lambda: decode(frames[0]), 500)],
        ["bridge: decode + frame algebra + Odometry CDR, per state (batches of 8)",
         f"{per_state:.1f}"],
        ["bridge: the Odometry's CDR alone (`cdr.odometry`, from its row)",
         us(lambda: cdr.odometry(4_000_000, "map", "glider_0", row), 500)],
        ["baseline: fill an rclpy Odometry with the same numbers + `serialize_message`",
         us(lambda: rclpy_odometry(odom), 500)],
        [f"bridge: an echo as Image CDR ({ECHO_SHAPE[0]} × {ECHO_SHAPE[1]} float32)",
         us(lambda: conv.convert("sensor_msgs/msg/Image", "0", echo, "/sonar_0/e"), 50)],
        ["baseline: fill an rclpy Image with the same samples + `serialize_message`",
         us(rclpy_image, 50)],
        ["rclpy: serialise the same samples as Float32MultiArray",
         us(lambda: serialize_message(array), 50)],
    ]


def run(out_dir: Path) -> str:
    ros_domain = 120 + int.from_bytes(os.urandom(1)) % 100
    with claim_first_free() as (dom, _), tempfile.TemporaryDirectory() as tmp_name:
        assert dom.number is not None
        tmp = Path(tmp_name)
        env = _env(dom, ros_domain)
        with StallProbe() as base_probe:
            base = _baseline(env, tmp)
        with StallProbe() as load_probe:
            load = _states_and_echoes(dom, env, tmp)
        with StallProbe() as floor_probe:
            floor = _states_and_echoes(dom, env, tmp, floor=True)
        with StallProbe() as single_probe:
            single = _states_and_echoes(dom, env, tmp, gliders=1, sonars=0, run_s=SINGLE_S)
        cmd = _commands(dom, env, tmp)
    costs = _costs()
    lat, period_ms = load["lat"], 1000.0 / STATE_HZ
    delivered = lat.size / load["expected"]
    ratio_p50 = _pct(lat, 50) / _pct(base, 50)
    effect = cmd["server"]["cmd_effect_ticks"]
    d = cmd["delays"]
    apply_ms = cmd["server"]["cmd_apply_ms"]
    applied_p99 = (_pct(d, 99) + float(apply_ms["p99"])) / period_ms
    def stalls(probe: StallProbe) -> str:
        return f"{probe.result['over_3ms']} / {probe.result['max_ms']:.1f}"

    def stages(r: dict[str, Any]) -> list[str]:
        return [f"{r['bus_ms']['p50']:.3f} / {r['bus_ms']['p99']:.3f}",
                f"{r['out_ms']['p50']:.3f} / {r['out_ms']['p99']:.3f}"]

    rows = [
        [f"DDS alone (rclpy → rclpy, {GLIDERS} × {STATE_HZ} Hz)", f"{base.size}",
         f"{_pct(base, 50):.3f}", f"{_pct(base, 99):.3f}", "–", "–", "–", "–",
         stalls(base_probe)],
        [f"echoloop → bridge → rclpy ({GLIDERS} × {STATE_HZ} Hz + echoes)", f"{lat.size}",
         f"{_pct(lat, 50):.3f}", f"{_pct(lat, 99):.3f}", *stages(load),
         f"{100 * delivered:.2f} %", f"{100 * load['cpu_share']:.1f} %", stalls(load_probe)],
        [f"floor: echoloop → a forwarder that does not convert → rclpy ({GLIDERS} × "
         f"{STATE_HZ} Hz + echoes)", f"{floor['lat'].size}", f"{_pct(floor['lat'], 50):.3f}",
         f"{_pct(floor['lat'], 99):.3f}", "–", "–",
         f"{100 * floor['lat'].size / floor['expected']:.2f} %",
         f"{100 * floor['cpu_share']:.1f} % (forwarder)", stalls(floor_probe)],
        [f"echoloop → bridge → rclpy (1 × {STATE_HZ} Hz, no echoes, {SINGLE_S:.0f} s)",
         f"{single['lat'].size}", f"{_pct(single['lat'], 50):.3f}",
         f"{_pct(single['lat'], 99):.3f}", *stages(single),
         f"{100 * single['lat'].size / single['expected']:.2f} %",
         f"{100 * single['cpu_share']:.1f} %", stalls(single_probe)],
    ]
    return (
        f"{__doc__.split(chr(10) + chr(10), 1)[1].strip()}\n\n"
        f"### States to rclpy ({RUN_S:.0f} s window)\n\n"
        + table(["path", "messages", "latency p50 ms", "p99 ms",
                 "of which the bus: p50 / p99 ms", "the bus + the bridge: p50 / p99 ms",
                 "delivered", "bridge CPU (one core)",
                 "platform stalls > 3 ms / latest ms (probe)"], rows)
        + f"\n\nBridge p50 / DDS-alone p50 (same run): **{ratio_p50:.2f}**. Echoes received in "
        f"the window: {load['echoes']} of {load['echoes_expected']} published. CPU of the other "
        "parties on the machine's 2 cores in the window: "
        + ", ".join(f"{k} {100 * v:.0f} %" for k, v in load["others"].items())
        + ". Goals: p50 ≤ 1 ms, p99 ≤ 3 ms, ≥ 99.9 % delivered, bridge ≤ 35 % of one core.\n\n"
        f"### Commands from ROS 2 ({CMD_HZ:.0f} Hz to glider {CMD_GLIDER}, states at "
        f"{STATE_HZ} Hz, {RUN_S:.0f} s)\n\n"
        + table(["commands sent", "found on the bus", "ROS 2 → bus p50 / p99 ms",
                 "server: arrival → applied p50 / p99 ms", "effect ticks p50 / p99",
                 "ROS 2 → applied p99 ≤ (state periods)"],
                [[f"{cmd['sent']}", f"{d.size}", f"{_pct(d, 50):.3f} / {_pct(d, 99):.3f}",
                  f"{apply_ms['p50']:.3f} / {apply_ms['p99']:.3f}",
                  f"{effect['p50']:.0f} / {effect['p99']:.0f}", f"{applied_p99:.2f}"]])
        + f"\n\nServer: {cmd['server']['cmd_applied']} commands applied, "
        f"{cmd['server']['cmd_rejected']} rejected; bridge: {cmd['bridge']['cmd_forwarded']} "
        "forwarded. Goal: applied p99 ≤ 2 state periods.\n\n"
        "### Cost per message in one process (no DDS)\n\n"
        + table(["work", "µs"], costs) + "\n"
    )
