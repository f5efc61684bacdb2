"""``bag export --ros2`` read with the mcap reader and deserialised by a fresh rosbags ROS 2
Jazzy type store: every topic gives back what the bus carried, and each schema in the file is
the type store's own definition."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from hil_bridge.bus.messages import GliderState, Message, SonarEcho, state_quaternion
from hil_bridge.recording.export.ros2 import DISTRO, MSG_DIR, export_ros2, typestore
from sim_core.pose import quat_conjugate, quat_from_euler, quat_rotate
from tests.hil_bridge.recording.bagmaker import demo_messages, write_bag


def _messages() -> list[tuple[str, Message, str]]:
    """The demo run plus a flown state (carrying its attitude and rates), a two-channel echo
    that carries its sonar pose and one that nothing locates (no mount, no pose)."""
    msgs = demo_messages()
    q = quat_from_euler(-0.3, 0.05, 1.0)
    msgs.append(("/glider/4/state", GliderState(
        stamp_ns=3_000_000_001, x=1.5, y=-2.5, z=80.0, heading=1.0, bank=0.3, airspeed=10.0,
        vz=-0.4, glider_id=4, roll=-0.3, pitch=0.05, yaw=1.0, qw=q[0], qx=q[1], qy=q[2],
        qz=q[3], roll_rate=0.01, pitch_rate=-0.02, yaw_rate=0.3), ""))
    two = np.arange(2 * 300, dtype=np.float32).reshape(2, 300) * 1e-4
    msgs.append(("/sonar/1/echo", SonarEcho(
        stamp_ns=3_100_000_000, ping_seq=7, fs=250e3, samples=two, leaves_in_beam=3,
        fidelity="exact", sonar_id=1, position=[1.0, 2.0, 3.0], orientation=q,
        boresight=quat_rotate(q, [1.0, 0.0, 0.0]), emit_ns=3_099_000_000), "glider/4"))
    msgs.append(("/sonar/2/echo", SonarEcho(
        stamp_ns=3_200_000_000, ping_seq=1, fs=100e3, samples=np.ones(50, np.float32),
        leaves_in_beam=0, fidelity="fast", sonar_id=2), ""))
    return msgs


def _read(path: Path) -> tuple[dict[str, str], dict[str, list[tuple[str, int, int, Any]]]]:
    """Schema texts by type, and per topic ``(type, log_time, publish_time, message)``,
    deserialised by a fresh Jazzy store that knows echoloop's types only from the file."""
    from mcap.reader import make_reader

    store = get_typestore(Stores.ROS2_JAZZY)
    schemas: dict[str, str] = {}
    out: dict[str, list[tuple[str, int, int, Any]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        for schema, channel, message in reader.iter_messages():
            assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
            if schema.name not in schemas:
                schemas[schema.name] = schema.data.decode()
                if schema.name.startswith("echoloop_msgs/"):
                    store.register(get_types_from_msg(schemas[schema.name], schema.name))
            value = store.deserialize_cdr(message.data, schema.name)
            out.setdefault(channel.topic, []).append(
                (schema.name, message.log_time, message.publish_time, value))
    return schemas, out


def _ns(stamp: Any) -> int:
    return int(stamp.sec) * 10**9 + int(stamp.nanosec)


def _vec(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def _wxyz(q: Any) -> list[float]:
    return [q.w, q.x, q.y, q.z]


def test_every_topic_deserialises_to_what_the_bus_carried(tmp_path: Path) -> None:
    msgs = _messages()
    src = write_bag(tmp_path / "run.mcap", msgs)
    counts = export_ros2(src, tmp_path / "ros2.mcap")
    assert counts.skipped == {} and counts.written == counts.messages + sum(
        isinstance(m, GliderState) for _, m, _ in msgs)
    schemas, got = _read(tmp_path / "ros2.mcap")
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    assert DISTRO == "jazzy"
    for name, text in schemas.items():
        assert text == typestore().generate_msgdef(name, ros_version=2)[0], name
        if not name.startswith("echoloop_msgs/"):  # standard types: Jazzy's, unchanged
            assert text == jazzy.generate_msgdef(name, ros_version=2)[0], name

    sent: dict[str, list[Any]] = {}
    for topic, m, _ in msgs:
        sent.setdefault(topic, []).append(m)
    assert set(got) == {*sent, "/tf"}
    for topic, recs in sent.items():
        rows = got[topic]
        assert len(rows) == len(recs), topic
        for (_, log_time, publish_time, value), rec in zip(rows, recs, strict=True):
            # write_bag logs each message 1 ms after its stamp; publish_time is the stamp
            assert log_time == 1_700_000_000_000_000_000 + rec.stamp_ns + 10**6
            assert publish_time == rec.stamp_ns
            stamp = value.clock if topic == "/clock" else (
                value.markers[0].header.stamp if topic == "/thermals" else value.header.stamp)
            assert _ns(stamp) == rec.stamp_ns, topic
    tf = {}
    for _, _, _, value in got["/tf"]:
        t = value.transforms[0]
        tf.setdefault(t.child_frame_id, []).append(t)

    for topic, recs in sent.items():
        values = [row[3] for row in got[topic]]
        for value, rec in zip(values, recs, strict=True):
            if isinstance(rec, GliderState):
                gid = int(topic.split("/")[2])
                assert (value.header.frame_id, value.child_frame_id) == ("map", f"glider_{gid}")
                pose = value.pose.pose
                assert _vec(pose.position) == [rec.x, rec.y, rec.z]
                q = state_quaternion(rec)
                np.testing.assert_allclose(_wxyz(pose.orientation), q, atol=1e-12)
                world_v = [rec.airspeed * math.cos(rec.heading),
                           rec.airspeed * math.sin(rec.heading), rec.vz]
                np.testing.assert_allclose(_vec(value.twist.twist.linear),
                                           quat_rotate(quat_conjugate(q), world_v), atol=1e-12)
                np.testing.assert_array_equal(
                    _vec(value.twist.twist.angular),
                    [rec.roll_rate, rec.pitch_rate, rec.yaw_rate])  # NaN: not given
                t = tf[f"glider_{gid}"].pop(0)
                assert _ns(t.header.stamp) == rec.stamp_ns and t.header.frame_id == "map"
                assert _vec(t.transform.translation) == [rec.x, rec.y, rec.z]
                assert _wxyz(t.transform.rotation) == _wxyz(pose.orientation)
            elif topic == "/forest/points":
                assert [(f.name, f.offset, f.datatype) for f in value.fields] == [
                    ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7)]
                pts = np.frombuffer(value.data.tobytes(), dtype="<f4").reshape(-1, 4)
                np.testing.assert_array_equal(pts[:, :3], rec.points)
                np.testing.assert_array_equal(pts[:, 3], rec.intensity)
                assert (value.width, value.row_step) == (len(rec.points), 16 * len(rec.points))
            elif topic == "/thermals":
                m = value.markers
                assert [k.type for k in m] == [3] * len(rec.x)
                assert [(k.pose.position.x, k.pose.position.y) for k in m] == list(
                    zip(rec.x, rec.y, strict=True))
                assert [k.scale.x for k in m] == list(2 * rec.radius)
                assert [_wxyz(k.pose.orientation) for k in m] == [[1.0, 0, 0, 0]] * len(m)
            elif topic.endswith("/ping"):
                assert (value.sonar_id, value.ping_seq, value.az, value.el, value.beamwidth,
                        value.encoding) == (rec.sonar_id, rec.ping_seq, rec.az, rec.el,
                                            rec.beamwidth, rec.encoding)
            elif topic.endswith("/echo"):
                samples = np.atleast_2d(rec.samples)
                assert (value.channels, value.n_samples) == samples.shape
                np.testing.assert_array_equal(value.samples.reshape(samples.shape), samples)
                assert (value.sonar_id, value.ping_seq, value.fs, value.leaves_in_beam,
                        value.fidelity, value.compute_ns) == (
                    rec.sonar_id, rec.ping_seq, rec.fs, rec.leaves_in_beam, rec.fidelity,
                    rec.compute_ns)
            elif topic.endswith("/cmd"):
                assert (value.glider_id, value.bank_cmd, value.airspeed_cmd, value.step) == (
                    rec.glider_id, rec.bank_cmd, rec.airspeed_cmd, rec.step)
    assert all(not left for left in tf.values())
    own, nowhere = got["/sonar/1/echo"][0][3], got["/sonar/2/echo"][0][3]
    assert own.pose_known and _vec(own.sonar_pose.position) == [1.0, 2.0, 3.0]
    rec_own = sent["/sonar/1/echo"][0]
    np.testing.assert_allclose(_vec(own.boresight), rec_own.boresight, atol=1e-15)
    # the frame's x is the boresight (export.common.sonar_pose)
    np.testing.assert_allclose(quat_rotate(_wxyz(own.sonar_pose.orientation), [1.0, 0, 0]),
                               rec_own.boresight, atol=1e-12)
    assert not nowhere.pose_known and _wxyz(nowhere.sonar_pose.orientation) == [1.0, 0, 0, 0]


def test_only_echoloops_own_types_ship_as_msg_files() -> None:
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    shipped = sorted(f"{p.parent.parent.name}/msg/{p.stem}" for p in MSG_DIR.rglob("*.msg"))
    assert shipped == ["echoloop_msgs/msg/GliderCmd", "echoloop_msgs/msg/SonarEcho",
                       "echoloop_msgs/msg/SonarPing"]
    assert not set(shipped) & set(jazzy.types)
    assert set(shipped) <= set(typestore().types)


def test_topics_without_a_ros2_type_are_counted_as_skipped(tmp_path: Path) -> None:
    from hil_bridge.bus.messages import Diagnostics

    src = write_bag(tmp_path / "run.mcap", [
        ("/diagnostics", Diagnostics(stamp_ns=0, node="n", counters={"sent": 1}), "")])
    counts = export_ros2(src, tmp_path / "ros2.mcap")
    assert counts.written == 0
    assert counts.skipped == {"no ROS 2 type for echoloop/Diagnostics": 1}
