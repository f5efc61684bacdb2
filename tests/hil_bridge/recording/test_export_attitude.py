"""One attitude everywhere: the bus message helpers, the live view and every exporter show a
state at the attitude :mod:`sim_core.flight` gives it (the quaternion a flown state carries;
for an old-style state without one, :func:`sim_core.flight.glide_attitude`). And the sonar
pose of an echo that carries it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import GliderState, SonarEcho, state_quaternion, state_quaternions
from hil_bridge.bus.transport import open_transport
from hil_bridge.cli import main as echoloop
from hil_bridge.recording.export.common import sonar_pose
from hil_bridge.tools.live import LiveView
from sim_core.flight import BANK, HEADING, SPEED, FlightModel, FlightParams, glide_attitude
from sim_core.pose import direction_from_az_el, quat_from_euler, quat_rotate
from sim_core.soaring import Law
from tests.hil_bridge.bus.bus_test_util import poll_until
from tests.hil_bridge.recording.bagmaker import read_foxglove, write_bag

#: every path carries the attitude as float64; they may differ only by rounding
TOL = 1e-12
_LAW = Law()
SBXC = (_LAW.Sink_A, _LAW.Sink_B, _LAW.Sink_C)


def _states() -> tuple[list[GliderState], np.ndarray]:
    """Glider states of five vehicles at two instants and the attitude sim_core.flight gives
    each: ids 0-2 flown by the flight model as the server publishes them (a glider climbing in
    a 2.5 m/s updraft, one sinking in still air, a vehicle holding its height), ids 3-4
    old-style (no attitude fields: NaN), one of them climbing in a thermal (vz > 0)."""
    model = FlightModel.from_params([FlightParams()] * 3, glide=[True, True, False],
                                    polar=SBXC)
    y = np.array([[0.0, 10.0, 20.0], [0.0, 5.0, -5.0], [300.0, 250.0, 50.0],
                  [0.4, -2.5, 3.0], [0.35, -0.2, 0.0], [11.0, 9.5, 8.0]])
    out = model.outputs(y, np.stack([y[BANK], y[SPEED]]), np.array([2.5, 0.0, 0.0]))
    old = np.array([[1.2, 0.3, 10.5, 1.5], [-0.7, -0.45, 13.0, -1.1]])  # heading bank V vz
    states, expected = [], []
    for k in range(2):
        t = k * 100_000_000
        for i in range(3):
            q = out.quat[i]
            states.append(GliderState(
                stamp_ns=t, x=float(y[0, i]), y=float(y[1, i]), z=float(y[2, i]),
                heading=float(y[HEADING, i]), bank=float(y[BANK, i]),
                airspeed=float(y[SPEED, i]), vz=float(out.vz[i]), glider_id=i, step=k,
                roll=float(out.roll[i]), pitch=float(out.pitch[i]), yaw=float(out.yaw[i]),
                qw=float(q[0]), qx=float(q[1]), qy=float(q[2]), qz=float(q[3]),
                roll_rate=float(out.rates[i, 0]), pitch_rate=float(out.rates[i, 1]),
                yaw_rate=float(out.rates[i, 2])))
            expected.append(q)
        for j, (h, b, v, vz) in enumerate(old):
            states.append(GliderState(stamp_ns=t, x=float(j), y=0.0, z=100.0, heading=h,
                                      bank=b, airspeed=v, vz=vz, glider_id=3 + j, step=k))
            expected.append(glide_attitude(h, b, v).quat)
    return states, np.array(expected)


def test_an_old_state_gets_the_attitude_the_flight_model_gives_a_glider() -> None:
    states, expected = _states()
    old = states[3]
    assert math.isnan(old.qw) and old.vz > 0  # climbing in a thermal, no attitude given
    y = np.array([[old.x], [old.y], [old.z], [old.heading], [old.bank], [old.airspeed]])
    flown = FlightModel.from_params([FlightParams()], glide=[True], polar=SBXC).outputs(
        y, [[old.bank], [old.airspeed]], [old.vz])
    np.testing.assert_allclose(state_quaternion(old), flown.quat[0], atol=TOL)
    # nose down by the polar's glide angle through the air, although the glider climbs
    assert float(flown.pitch[0]) > 0
    np.testing.assert_allclose(state_quaternions(states), expected, atol=TOL)
    for st, q in zip(states, expected, strict=True):
        np.testing.assert_allclose(state_quaternion(st), q, atol=TOL)


def test_live_view_and_every_exporter_show_one_attitude(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader
    from scipy.io import loadmat

    states, expected = _states()
    ids = [st.glider_id for st in states[:5]]
    want = {st.glider_id: q for st, q in zip(states, expected, strict=True) if st.step == 1}
    got: dict[str, dict[int, list[np.ndarray]]] = {}

    def keep(path: str, gid: int, q: object) -> None:
        got.setdefault(path, {}).setdefault(gid, []).append(np.asarray(q, dtype=np.float64))

    bus = "mem://live_attitude"
    view = LiveView("live", bus=bus, port=0, rate_hz=50.0)
    view.start()
    try:
        with open_transport(bus) as raw:
            for seq, st in enumerate(states):
                raw.publish(encode(f"/glider/{st.glider_id}/state", st, seq=seq, pub_ns=0))
            assert poll_until(lambda: view.stats()["received"] == len(states)), view.stats()
    finally:
        view.stop()
    for gid, (_x, _y, _z, q, _alive) in view.poses().items():
        keep("live view", gid, q)

    src = write_bag(tmp_path / "run.mcap",
                    [(f"/glider/{st.glider_id}/state", st, "") for st in states])
    out = {"ros2": tmp_path / "ros2.mcap", "foxglove": tmp_path / "fox.mcap",
           "mat": tmp_path / "run.mat"}
    for kind, dst in out.items():
        assert echoloop(["bag", "export", str(src), f"--{kind}", str(dst)]) == 0
    with AnyReader([out["ros2"]]) as reader:
        for conn, _, raw_msg in reader.messages():
            msg = reader.deserialize(raw_msg, conn.msgtype)
            if conn.msgtype == "nav_msgs/msg/Odometry":
                o = msg.pose.pose.orientation
                keep("ros2 odometry", int(msg.child_frame_id[7:]), [o.w, o.x, o.y, o.z])
            else:
                tf = msg.transforms[0]
                r = tf.transform.rotation
                keep("ros2 /tf", int(tf.child_frame_id[7:]), [r.w, r.x, r.y, r.z])
    for _, value in read_foxglove(out["foxglove"])["/tf"]:
        tf = value.transforms[0]
        r = tf.rotation
        keep("foxglove /tf", int(tf.child_frame_id[7:]), [r.w, r.x, r.y, r.z])
    gliders = loadmat(out["mat"])["gliders"][0, 0]
    for gid in ids:
        for q in gliders[f"glider_{gid}"][0, 0]["quat"]:
            keep("mat", gid, q)

    every = {st.glider_id: [q for s, q in zip(states, expected, strict=True)
                            if s.glider_id == st.glider_id] for st in states}
    assert set(got) == {"live view", "ros2 odometry", "ros2 /tf", "foxglove /tf", "mat"}
    for path, per_id in got.items():
        assert sorted(per_id) == ids, path
        for gid, quats in per_id.items():
            reference = [want[gid]] if path == "live view" else every[gid]
            np.testing.assert_allclose(quats, reference, atol=TOL, err_msg=f"{path} {gid}")


def test_an_echo_with_its_pose_gives_a_frame_along_its_boresight() -> None:
    sonar = quat_from_euler(-0.5, 0.3, 2.0)  # a banked vehicle's downward-looking sonar
    bore = quat_rotate(sonar, direction_from_az_el(0.4, -0.1))
    echo = SonarEcho(stamp_ns=0, ping_seq=1, fs=1e5, samples=np.zeros(4), leaves_in_beam=0,
                     fidelity="fast", position=[1.0, 2.0, 3.0], orientation=sonar,
                     boresight=bore, emit_ns=7)
    pose = sonar_pose(echo, None, None)
    assert pose is not None
    np.testing.assert_allclose(quat_rotate(pose.orientation, [1.0, 0, 0]), bore, atol=1e-12)
    np.testing.assert_array_equal(pose.position, [1.0, 2.0, 3.0])
    old = SonarEcho(stamp_ns=0, ping_seq=1, fs=1e5, samples=np.zeros(4), leaves_in_beam=0,
                    fidelity="fast")
    assert sonar_pose(old, None, None) is None  # no pose and no mount state: not located


@pytest.mark.parametrize("bad", [0.0, -3.0])
def test_an_old_state_without_airspeed_is_shown_level(bad: float) -> None:
    st = GliderState(stamp_ns=0, x=0.0, y=0.0, z=0.0, heading=0.5, bank=0.2, airspeed=bad,
                     vz=-1.0)
    np.testing.assert_allclose(state_quaternion(st), quat_from_euler(-0.2, 0.0, 0.5), atol=TOL)
