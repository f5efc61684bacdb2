"""Exports take the attitude the server publishes, and derive it only for older messages."""

from __future__ import annotations

import numpy as np

from hil_bridge.bus.messages import GliderState, SonarEcho
from hil_bridge.recording.export.common import glider_attitudes, sonar_pose
from sim_core.pose import direction_from_az_el, quat_from_euler, quat_rotate


def _state(**kw: float) -> GliderState:
    return GliderState(stamp_ns=0, x=0.0, y=0.0, z=100.0, heading=1.0, bank=0.3, airspeed=10.0,
                       vz=0.0, **kw)


def test_states_with_a_quaternion_keep_it_older_ones_derive_it() -> None:
    q = quat_from_euler(-0.3, 0.05, 1.0)
    flown = _state(qw=q[0], qx=q[1], qy=q[2], qz=q[3])
    old = _state()  # NaN attitude: a recording older than the attitude fields
    got = glider_attitudes([flown, old])
    np.testing.assert_array_equal(got[0], q)
    np.testing.assert_allclose(got[1], quat_from_euler(-0.3, 0.0, 1.0), atol=1e-15)


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
