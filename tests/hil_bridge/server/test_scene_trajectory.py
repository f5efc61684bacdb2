"""Trajectory interpolation and trajectory files (sim_core.scene)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_bridge.files.soaring import load_law, save_trace_npz, write_trace_csv
from hil_bridge.recording.logs import load_trajectory
from sim_core.trajectory import Trajectory


def _square() -> Trajectory:
    t = np.array([0.0, 1.0, 2.0, 3.0])
    xyz = np.array([[0, 0, 10], [10, 0, 12], [10, 10, 14], [0, 10, 14]], dtype=float)
    heading = np.array([0.0, np.pi / 2, np.pi, -np.pi / 2 + 2 * np.pi])
    return Trajectory(t, xyz, heading, np.zeros(4), np.full(4, 10.0))


def test_linear_position_and_vz() -> None:
    s = _square().sample(np.array([0.5, 1.25, 3.0]))
    np.testing.assert_allclose(s["x"], [5.0, 10.0, 0.0])
    np.testing.assert_allclose(s["y"], [0.0, 2.5, 10.0])
    np.testing.assert_allclose(s["z"], [11.0, 12.5, 14.0])
    np.testing.assert_allclose(s["vz"], [2.0, 2.0, 0.0])


def test_heading_takes_the_shortest_arc_across_pi() -> None:
    t = np.array([0.0, 1.0])
    xyz = np.zeros((2, 3))
    traj = Trajectory(t, xyz, np.array([3.0, -3.0]), np.zeros(2), np.ones(2))
    h = float(traj.sample(0.5)["heading"])
    # 3.0 -> -3.0 the short way passes through pi (0.283 rad), not through 0 (6 rad).
    assert abs(abs(h) - np.pi) < 1e-9


def test_clamp_and_loop() -> None:
    traj = _square()
    np.testing.assert_allclose(traj.sample(10.0)["x"], 0.0)
    np.testing.assert_allclose(traj.sample(10.0)["y"], 10.0)
    looped = Trajectory(traj.t, traj.xyz, traj.heading, traj.bank, traj.airspeed, loop=True)
    np.testing.assert_allclose(looped.sample(3.5)["x"], 5.0)  # 3.5 wraps to 0.5


def test_bad_arrays_are_rejected_by_name() -> None:
    with pytest.raises(ValueError, match="t: expected strictly increasing"):
        Trajectory(np.array([0.0, 0.0]), np.zeros((2, 3)), np.zeros(2), np.zeros(2), np.ones(2))
    with pytest.raises(ValueError, match="xyz: expected shape"):
        Trajectory(np.array([0.0, 1.0]), np.zeros((2, 2)), np.zeros(2), np.zeros(2), np.ones(2))
    with pytest.raises(ValueError, match="heading: contains non-finite"):
        Trajectory(
            np.array([0.0, 1.0]), np.zeros((2, 3)), np.array([0, np.nan]), np.zeros(2), np.ones(2)
        )


def test_from_path_times_by_arc_length_and_banks_on_turns() -> None:
    th = np.linspace(0, 2 * np.pi, 721)
    r, v = 20.0, 5.0
    xyz = np.stack([r * np.cos(th), r * np.sin(th), np.full_like(th, 3.0)], axis=1)
    traj = Trajectory.from_path(xyz, None, speed_mps=v)
    assert traj.duration == pytest.approx(2 * np.pi * r / v, rel=1e-4)
    # coordinated turn: tan(bank) = v^2 / (g r)
    np.testing.assert_allclose(traj.bank[10:-10], np.arctan(v * v / (9.81 * r)), rtol=1e-3)


def _ring(n: int, r: float, *, turns: float = 1.0) -> np.ndarray:
    """``n`` chords of a circle of radius ``r`` at 3 m, closed (the last point is the first)."""
    a = np.linspace(0.0, 2 * np.pi * turns, n + 1)
    xyz = np.stack([r * np.cos(a), r * np.sin(a), np.full_like(a, 3.0)], axis=1)
    xyz[-1] = xyz[0]
    return xyz


def test_a_looped_circle_banks_atan_v2_over_rg_everywhere_and_at_its_join() -> None:
    """Coordinated turn, tan(bank) = V^2 / (R g), at every sample, the join's two included (the
    loop's neighbours are periodic); across the wrap the bank moves less than the flight
    model's roll-rate limit allows in that time. Tolerance: a chord polygon's heading rate is
    V/R (1 + (pi/n)^2 / 6 + ...), 1.3e-5 relative at n = 360."""
    from sim_core.flight import FlightParams

    r, v = 20.0, 5.0
    traj = Trajectory.from_path(_ring(360, r), None, speed_mps=v, loop=True)
    np.testing.assert_allclose(traj.bank, np.arctan(v * v / (9.81 * r)), rtol=1e-4)
    dt = float(traj.t[1] - traj.t[0])
    end = traj.t[-1]
    across = traj.sample(np.array([end - dt / 2, end, end + dt / 2]))
    assert np.all(np.abs(np.diff(across["bank"])) <= FlightParams().bank_rate_max * dt / 2)
    heading_step = np.abs(np.angle(np.exp(1j * np.diff(across["heading"]))))
    assert np.all(heading_step <= v / r * dt / 2 * (1 + 1e-4))


def test_a_looped_square_banks_at_its_join_as_at_its_other_corners() -> None:
    """A square of 0.5 m steps (as a ``points`` path is densified): each corner banks the two
    samples around it (a central difference over one 90-degree turn); the join is a corner like
    the others, not a one-sample glitch, so its bank equals the bank one sample away there."""
    from sim_core.scene.runtime import _densify

    side = 10.0
    corners = np.array([[0, 0, 3], [side, 0, 3], [side, side, 3], [0, side, 3], [0, 0, 3]],
                       dtype=float)
    traj = Trajectory.from_path(_densify(corners, 0.5), None, speed_mps=3.0, loop=True)
    per_side = int(side / 0.5)
    assert len(traj) == 4 * per_side + 1
    dt = 0.5 / 3.0
    corner_bank = np.arctan(3.0 * (np.pi / 2) / (2 * dt) / 9.81)
    bank = traj.bank
    for k in range(1, 4):  # the corners inside the path: samples k * per_side - 1 and k * per_side
        np.testing.assert_allclose(bank[k * per_side - 1:k * per_side + 1], corner_bank,
                                   rtol=1e-9)
    np.testing.assert_allclose(bank[[-2, -1, 0]], corner_bank, rtol=1e-9)  # the join
    straight = np.ones(len(traj), dtype=bool)
    straight[[k * per_side + d for k in range(5) for d in (-1, 0) if 0 <= k * per_side + d]] = 0
    np.testing.assert_allclose(bank[straight], 0.0, atol=1e-12)


def test_an_open_path_keeps_its_one_sided_ends() -> None:
    """Without ``loop`` the ends are ends: the last sample repeats the last segment's heading and
    the heading rate there is one-sided (np.gradient's), as before loops were periodic."""
    xyz = _ring(360, 20.0, turns=0.5)[:-1]
    traj = Trajectory.from_path(xyz, None, speed_mps=5.0, loop=False)
    assert traj.heading[-1] == traj.heading[-2]
    assert traj.bank[-1] == pytest.approx(0.0, abs=1e-12)


def test_csv_single_and_multi_vehicle(tmp_path: Path) -> None:
    single = tmp_path / "one.csv"
    single.write_text(
        "t,x,y,z,heading,bank,airspeed\n0,0,0,5,0,0,10\n2,20,0,5,0,0.1,10\n", encoding="utf-8"
    )
    s = load_trajectory(single).sample(1.0)
    assert (float(s["x"]), float(s["bank"])) == pytest.approx((10.0, 0.05))
    multi = tmp_path / "trace.csv"
    multi.write_text(
        "t,id,x,y,z,heading,bank,airspeed,vz,alive\n"
        "0,0,0,0,100,0,0,10,0,1\n0,1,50,0,100,1,0,10,0,1\n"
        "1,0,10,0,100,0,0,10,0,1\n1,1,50,10,100,1,0,10,0,1\n"
        "2,1,50,20,100,1,0,10,0,0\n",
        encoding="utf-8",
    )
    with pytest.raises(ValueError, match="choose one"):
        load_trajectory(multi)
    with pytest.raises(ValueError, match="no rows for id 7"):
        load_trajectory(multi, vehicle_id=7)
    one = load_trajectory(multi, vehicle_id=1)
    assert len(one) == 2  # the dead row is dropped
    assert float(one.sample(0.5)["y"]) == pytest.approx(5.0)


def test_npz_and_missing_columns(tmp_path: Path) -> None:
    path = tmp_path / "run.npz"
    cols = {c: np.array([0.0, 1.0]) for c in ("t", "x", "y", "heading", "bank")}
    np.savez(path, **cols)
    with pytest.raises(ValueError, match=r"missing column\(s\) \['z'\]"):
        load_trajectory(path)
    np.savez(path, **cols, z=np.array([5.0, 5.0]))  # no airspeed: the track speed, sqrt(2)
    assert float(load_trajectory(path).sample(0.5)["airspeed"]) == pytest.approx(2**0.5)
    np.savez(path, **cols, z=np.array([5.0, 5.0]), airspeed=np.array([3.0, 4.0]))
    assert float(load_trajectory(path).sample(0.5)["airspeed"]) == pytest.approx(3.5)


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.floats(0.01, 10.0), min_size=1, max_size=20),
    turns=st.lists(st.floats(-3.1, 3.1), min_size=21, max_size=21),
    start=st.floats(-1e4, 1e4),
)
def test_sampling_hits_the_samples_and_heading_stays_on_the_short_arc(
    steps: list[float], turns: list[float], start: float
) -> None:
    t = np.concatenate([[0.0], np.cumsum(steps)])
    k = t.size
    heading = start + np.cumsum(turns[:k])  # consecutive samples less than pi apart
    xyz = np.stack([t * 3.0, -t, np.full(k, 5.0)], axis=1)
    traj = Trajectory(t, xyz, heading, np.zeros(k), np.full(k, 8.0))
    s = traj.sample(t)
    np.testing.assert_allclose(s["x"], xyz[:, 0], atol=1e-9)
    wrapped = (heading + np.pi) % (2 * np.pi) - np.pi
    diff = (s["heading"] - wrapped + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(diff, 0.0, atol=1e-7)
    # midway between two samples the heading is within the short arc between them
    mid = traj.sample((t[:-1] + t[1:]) / 2)["heading"]
    arc = np.abs(np.asarray(turns[1:k]))
    off = np.abs((mid - wrapped[:-1] + np.pi) % (2 * np.pi) - np.pi)
    assert np.all(off <= arc / 2 + 1e-7)


def test_swarm_trace_csv_and_npz_replay_the_same_glider(tmp_path: Path) -> None:
    from sim_core.soaring import SwarmSim

    sim = SwarmSim(load_law("default", {"numAgents": 3, "totalTime": 10}), seed=1,
                   trace=True)
    while not sim.done:
        sim.step()
    trace = sim.trace()
    write_trace_csv(trace, tmp_path / "trace.csv")
    save_trace_npz(trace, tmp_path / "trace.npz")
    from_csv = load_trajectory(tmp_path / "trace.csv", vehicle_id=2)
    from_npz = load_trajectory(tmp_path / "trace.npz", vehicle_id=2)
    np.testing.assert_allclose(from_csv.xyz, from_npz.xyz, rtol=1e-12)
    np.testing.assert_allclose(from_npz.xyz[:, 0], trace.x[:, 2])
    with pytest.raises(ValueError, match="choose one"):
        load_trajectory(tmp_path / "trace.npz")
    with pytest.raises(ValueError, match="no vehicle 5"):
        load_trajectory(tmp_path / "trace.npz", vehicle_id=5)


def test_logged_attitude_is_carried_and_slerped() -> None:
    from sim_core.pose import quat_from_euler

    t = np.array([0.0, 1.0, 2.0])
    yaw = np.array([0.0, 0.4, 0.8])
    q = quat_from_euler(np.full(3, -0.2), np.zeros(3), yaw)
    traj = Trajectory(t, np.zeros((3, 3)), yaw, np.full(3, 0.2), np.ones(3), quat=-q)
    mid = traj.attitude(np.array([0.5, 1.5, 9.0]))
    assert mid is not None
    expected = quat_from_euler(np.full(3, -0.2), np.zeros(3), np.array([0.2, 0.6, 0.8]))
    # stored with w >= 0 whatever the sign given; a constant-axis turn slerps exactly
    np.testing.assert_allclose(mid, expected, atol=1e-12)
    assert Trajectory(t, np.zeros((3, 3)), yaw, yaw, np.ones(3)).attitude(0.5) is None
    with pytest.raises(ValueError, match=r"quat: expected shape \(3, 4\)"):
        Trajectory(t, np.zeros((3, 3)), yaw, yaw, np.ones(3), quat=np.zeros((2, 4)))


def test_a_scene_reads_logged_paths_only_through_its_reader(tmp_path: Path) -> None:
    from hil_bridge.files.scene import load_scene
    from sim_core.config import ConfigError

    path = tmp_path / "one.csv"
    path.write_text("t,x,y,z\n0,0,0,5\n2,20,0,5\n", encoding="utf-8")
    spec = {"vehicles": [{"id": 3, "path": {"kind": "file", "file": str(path), "loop": False,
                                            "origin": None}}]}
    with pytest.raises(ConfigError, match="needs a trajectory reader"):
        load_scene(spec)
    scene = load_scene(spec, trajectory_reader=load_trajectory)
    assert float(scene.trajectories[3].sample(1.0)["x"]) == pytest.approx(10.0)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 40), st.booleans(), st.integers(0, 2**31 - 1))
def test_sampling_many_paths_at_once_is_np_interp_value_for_value(
    k: int, loop: bool, seed: int
) -> None:
    from sim_core.trajectory import sample_paths

    rng = np.random.default_rng(seed)
    trajs = []
    for _ in range(3):
        t = np.cumsum(rng.uniform(0.01, 3.0, k)) + rng.uniform(-5.0, 5.0)
        trajs.append(Trajectory(t, rng.normal(size=(k, 3)) * 1e3, rng.uniform(-3, 3, k),
                                rng.normal(size=k), rng.uniform(1.0, 20.0, k), loop=loop))
    times = np.stack([np.concatenate([rng.uniform(tr.t[0] - 9, tr.t[-1] + 9, 20), tr.t])
                      for tr in trajs])
    got = sample_paths(trajs, times)
    for v, tr in enumerate(trajs):
        tq = (tr.t[0] + np.mod(times[v] - tr.t[0], tr.duration) if loop
              else np.clip(times[v], tr.t[0], tr.t[-1]))
        for key, col in (("x", tr.xyz[:, 0]), ("y", tr.xyz[:, 1]), ("z", tr.xyz[:, 2]),
                         ("bank", tr.bank), ("airspeed", tr.airspeed)):
            np.testing.assert_array_equal(got[key][v], np.interp(tq, tr.t, col))
        single = tr.sample(times[v])
        for key, value in single.items():
            np.testing.assert_array_equal(got[key][v], value)
