"""``bag export --ros2/--foxglove/--mat`` read back by independent readers, field by field:
rosbags (with the definitions embedded in the file), the mcap library with the protobuf
schemas in the file (mcap-protobuf-support), and scipy."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.bus.messages import state_quaternion
from hil_bridge.cli import main as echoloop
from sim_core.pose import quat_rotate
from tests.hil_bridge.recording.bagmaker import demo_messages, read_foxglove, write_bag


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, list]:
    msgs = demo_messages()
    return write_bag(tmp_path / "run.mcap", msgs), msgs


def _of(msgs: list, topic: str) -> list:
    return [m for t, m, _ in msgs if t == topic]


def test_ros2_export_read_back_by_rosbags(recording: tuple[Path, list], tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    src, msgs = recording
    out = tmp_path / "run_ros2.mcap"
    assert echoloop(["bag", "export", str(src), "--ros2", str(out)]) == 0
    with AnyReader([out]) as reader:  # no default typestore: only the embedded definitions
        types = {c.topic: c.msgtype for c in reader.connections}
        got: dict[str, list] = {}
        for conn, _, raw in reader.messages():
            got.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert types["/clock"] == "rosgraph_msgs/msg/Clock"
    assert types["/glider/9/state"] == "nav_msgs/msg/Odometry"
    assert types["/tf"] == "tf2_msgs/msg/TFMessage"
    assert types["/forest/points"] == "sensor_msgs/msg/PointCloud2"
    assert types["/thermals"] == "visualization_msgs/msg/MarkerArray"
    assert types["/sonar/0/echo"] == "echoloop_msgs/msg/SonarEcho"
    assert types["/sonar/0/ping"] == "echoloop_msgs/msg/SonarPing"
    assert types["/glider/0/cmd"] == "echoloop_msgs/msg/GliderCmd"
    for clock, rec in zip(got["/clock"], _of(msgs, "/clock"), strict=True):
        assert clock.clock.sec * 10**9 + clock.clock.nanosec == rec.stamp_ns
    states = _of(msgs, "/glider/1/state")
    for odo, st in zip(got["/glider/1/state"], states, strict=True):
        assert odo.header.stamp.sec * 10**9 + odo.header.stamp.nanosec == st.stamp_ns
        assert (odo.header.frame_id, odo.child_frame_id) == ("map", "glider_1")
        p, q = odo.pose.pose.position, odo.pose.pose.orientation
        assert (p.x, p.y, p.z) == (st.x, st.y, st.z)
        np.testing.assert_allclose([q.w, q.x, q.y, q.z], state_quaternion(st), atol=1e-12)
        # body-frame twist: airspeed along the heading plus vz, seen from the glider
        v = odo.twist.twist.linear
        assert math.hypot(v.x, v.y, v.z) == pytest.approx(math.hypot(st.airspeed, st.vz))
    tf_children = [t.transforms[0].child_frame_id for t in got["/tf"]]
    assert tf_children.count("glider_9") == 20 and len(tf_children) == 60
    cloud, rec_cloud = got["/forest/points"][0], _of(msgs, "/forest/points")[0]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
    assert (cloud.width, cloud.point_step) == (500, 16)
    pts = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(-1, 4)
    np.testing.assert_array_equal(pts[:, :3], rec_cloud.points)
    np.testing.assert_array_equal(pts[:, 3], rec_cloud.intensity)
    markers = got["/thermals"][0].markers
    th = _of(msgs, "/thermals")[0]
    assert [m.type for m in markers] == [3, 3]
    assert [m.pose.position.x for m in markers] == list(th.x)
    assert [m.scale.x for m in markers] == list(2 * th.radius)
    echoes, rec_echoes = got["/sonar/0/echo"], _of(msgs, "/sonar/0/echo")
    for e, rec in zip(echoes, rec_echoes, strict=True):
        np.testing.assert_array_equal(np.asarray(e.samples, dtype=np.float32), rec.samples)
        assert (e.ping_seq, e.fs, e.leaves_in_beam, e.fidelity) == (
            rec.ping_seq, rec.fs, rec.leaves_in_beam, rec.fidelity)
        assert (e.channels, e.n_samples) == (1, rec.samples.size)
        assert e.pose_known
    first_ping = _of(msgs, "/sonar/0/ping")[0]
    mount = [m for m in _of(msgs, "/glider/9/state") if m.stamp_ns <= first_ping.stamp_ns][-1]
    pose = echoes[0].sonar_pose.position
    assert (pose.x, pose.y, pose.z) == (mount.x, mount.y, mount.z)
    b = echoes[0].boresight
    yaw = mount.heading + first_ping.az
    np.testing.assert_allclose([b.x, b.y, b.z], [math.cos(first_ping.el) * math.cos(yaw),
                                                 math.cos(first_ping.el) * math.sin(yaw),
                                                 math.sin(first_ping.el)], atol=1e-12)
    ping = got["/sonar/0/ping"][0]
    assert (ping.az, ping.el, ping.beamwidth) == (first_ping.az, first_ping.el,
                                                  first_ping.beamwidth)
    cmd, rec_cmd = got["/glider/0/cmd"][3], _of(msgs, "/glider/0/cmd")[3]
    assert (cmd.bank_cmd, cmd.airspeed_cmd, cmd.step) == (rec_cmd.bank_cmd,
                                                          rec_cmd.airspeed_cmd, rec_cmd.step)


def test_foxglove_export_read_back_with_the_embedded_schemas(
    recording: tuple[Path, list], tmp_path: Path
) -> None:
    src, msgs = recording
    out = tmp_path / "run_fox.mcap"
    assert echoloop(["bag", "export", str(src), "--foxglove", str(out)]) == 0
    got = read_foxglove(out)
    assert {name for name, _ in got["/tf"]} == {"foxglove.FrameTransforms"}
    assert {name for name, _ in got["/gliders"]} == {"foxglove.SceneUpdate"}
    assert got["/forest/points"][0][0] == "foxglove.PointCloud"
    assert got["/thermals"][0][0] == "foxglove.SceneUpdate"
    assert got["/sonar/0/beam"][0][0] == "foxglove.SceneUpdate"
    states = _of(msgs, "/glider/0/state")
    tfs = [v.transforms[0] for _, v in got["/tf"] if v.transforms[0].child_frame_id == "glider_0"]
    for tf, st in zip(tfs, states, strict=True):
        assert tf.parent_frame_id == "world"
        assert (tf.translation.x, tf.translation.y, tf.translation.z) == (st.x, st.y, st.z)
        assert tf.timestamp.seconds * 10**9 + tf.timestamp.nanos == st.stamp_ns
        r = tf.rotation
        np.testing.assert_allclose([r.w, r.x, r.y, r.z], state_quaternion(st), atol=1e-12)
    last = got["/gliders"][-1][1]
    assert sorted(e.id for e in last.entities) == ["glider_0", "glider_1", "glider_9"]
    th = _of(msgs, "/thermals")[0]
    cyl = got["/thermals"][0][1].entities[0].cylinders
    assert [c.size.x for c in cyl] == list(2 * th.radius)
    assert [c.pose.position.y for c in cyl] == list(th.y)
    cloud = got["/forest/points"][0][1]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
    pts = np.frombuffer(cloud.data, dtype="<f4").reshape(-1, 4)
    np.testing.assert_array_equal(pts[:, :3], _of(msgs, "/forest/points")[0].points)
    # the beam cone: apex at the sonar, axis along the boresight, width of the ping
    beam = got["/sonar/0/beam"][0][1].entities[0].cylinders[0]
    ping, echo = _of(msgs, "/sonar/0/ping")[0], _of(msgs, "/sonar/0/echo")[0]
    length = echo.samples.size / echo.fs * 340.0 / 2
    assert beam.size.z == pytest.approx(length)
    assert beam.size.x == pytest.approx(2 * length * math.tan(ping.beamwidth / 2))
    assert (beam.bottom_scale, beam.top_scale) == (0.0, 1.0)
    o = beam.pose.orientation
    axis = quat_rotate([o.w, o.x, o.y, o.z], [0.0, 0.0, 1.0])
    mount = [m for m in _of(msgs, "/glider/9/state") if m.stamp_ns <= ping.stamp_ns][-1]
    yaw = mount.heading + ping.az
    np.testing.assert_allclose(axis, [math.cos(ping.el) * math.cos(yaw),
                                      math.cos(ping.el) * math.sin(yaw), math.sin(ping.el)],
                               atol=1e-9)
    centre = np.array([beam.pose.position.x, beam.pose.position.y, beam.pose.position.z])
    np.testing.assert_allclose(centre - axis * length / 2, [mount.x, mount.y, mount.z],
                               atol=1e-9)
    env = got["/sonar/0/echo"][0][1]
    assert env["ping_seq"] == echo.ping_seq and len(env["range_m"]) == len(env["envelope_db"])
    assert len(env["envelope_db"]) == 2000
    assert env["peak"] == pytest.approx(float(np.abs(echo.samples).max()), rel=1e-6)
    assert env["range_m"][-1] == pytest.approx(echo.samples.size / echo.fs * 170.0, rel=1e-3)


def test_mat_export_read_by_scipy(recording: tuple[Path, list], tmp_path: Path) -> None:
    from scipy.io import loadmat

    src, msgs = recording
    out = tmp_path / "run.mat"
    assert echoloop(["bag", "export", str(src), "--mat", str(out)]) == 0
    m = loadmat(out, squeeze_me=False)
    e = m["echoes"][0, 0]
    rec = _of(msgs, "/sonar/0/echo")
    pings = _of(msgs, "/sonar/0/ping")
    assert e["samples"].shape == (len(rec), 1)
    for k, r in enumerate(rec):
        np.testing.assert_array_equal(e["samples"][k, 0][:, 0], r.samples)
        assert int(e["stamp_ns"][k, 0]) == r.stamp_ns
        assert float(e["beamwidth"][k, 0]) == pings[k].beamwidth
        assert int(e["ping_stamp_ns"][k, 0]) == pings[k].stamp_ns
    assert e["position"].shape == (len(rec), 3) and e["orientation"].shape == (len(rec), 4)
    assert np.all(np.isfinite(e["boresight"]))
    g = m["gliders"][0, 0]["glider_1"][0, 0]
    states = _of(msgs, "/glider/1/state")
    np.testing.assert_array_equal(g["x"][:, 0], [s.x for s in states])
    np.testing.assert_array_equal(g["t"][:, 0], [s.stamp_ns * 1e-9 for s in states])
    np.testing.assert_allclose(g["quat"], [state_quaternion(s) for s in states], atol=1e-15)
    c = m["commands"][0, 0]["glider_0"][0, 0]
    assert c["bank_cmd"].shape == (20, 1)
    np.testing.assert_array_equal(m["thermals"][0, 0]["radius"][:, 0],
                                  _of(msgs, "/thermals")[0].radius)


def test_export_refuses_existing_outputs_and_its_input(
    recording: tuple[Path, list], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src, _ = recording
    out = tmp_path / "x.mcap"
    out.write_bytes(b"keep")
    assert echoloop(["bag", "export", str(src), "--ros2", str(out)]) == 1
    assert "x.mcap: exists; pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"keep"
    assert echoloop(["bag", "export", str(src), "--foxglove", str(out), "--overwrite"]) == 0
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"
    assert echoloop(["bag", "export", str(src), "--mat", str(src), "--overwrite"]) == 1
    assert "is also an input" in capsys.readouterr().err
