"""Continuous flight model: closed-form glide and turn, first-order bank response, convergence
in dt against a tight scipy reference, attitude consistency, height limits."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sim_core.flight import (
    BANK,
    HEADING,
    SPEED,
    FlightModel,
    FlightParams,
    X,
    Y,
    Z,
    attitude,
    glide_attitude,
)
from sim_core.pose import body_rates_from_quats, euler_from_quat, quat_from_euler, quat_rotate

POLAR = (-0.01843, 0.3782, -2.3782)
G = 9.81


def _model(glide: bool = True, **kw: float) -> FlightModel:
    return FlightModel.from_params([FlightParams(**kw)], glide=[glide], polar=POLAR)


def _state(x: float = 0.0, y: float = 0.0, z: float = 1000.0, psi: float = 0.0,
           bank: float = 0.0, v: float = 10.0) -> np.ndarray:
    return np.array([[x], [y], [z], [psi], [bank], [v]], dtype=float)


def _sink(v: float, bank: float = 0.0) -> float:
    a, b, c = POLAR
    return (a * v * v + b * v + c) / math.sqrt(math.cos(bank))


def test_still_air_glide_is_the_polar_sink_exactly() -> None:
    m = _model()
    y, grounded = m.step(_state(psi=0.3), [[0.0], [10.0]], 60.0, substeps=600)
    assert not grounded.any()
    assert y[Z, 0] == pytest.approx(1000.0 + 60.0 * _sink(10.0), abs=1e-9)
    assert y[X, 0] == pytest.approx(600.0 * math.cos(0.3), abs=1e-9)
    assert y[Y, 0] == pytest.approx(600.0 * math.sin(0.3), abs=1e-9)
    # the documented minimum sink of the SB-XC polar: -0.438 m/s at 10.26 m/s
    assert _sink(-POLAR[1] / (2 * POLAR[0])) == pytest.approx(-0.438, abs=5e-4)


@pytest.mark.parametrize("bank", [0.1, math.radians(30.0), -math.radians(45.0)])
def test_steady_turn_radius_rate_sink_and_attitude(bank: float) -> None:
    v = 12.0
    radius = v * v / (G * math.tan(abs(bank)))
    omega = G * math.tan(bank) / v
    m = _model()
    y0 = _state(bank=bank, v=v)
    t_end = 2 * math.pi / abs(omega) * 0.75
    y, _ = m.step(y0, [[bank], [v]], t_end, substeps=4000)
    # the centre of the circle is a quarter turn to the left (bank > 0) or right of the start
    cx, cy = 0.0, math.copysign(radius, bank)
    assert math.hypot(y[X, 0] - cx, y[Y, 0] - cy) == pytest.approx(radius, rel=1e-9)
    assert y[HEADING, 0] == pytest.approx(omega * t_end, rel=1e-12)
    assert y[Z, 0] == pytest.approx(1000.0 + t_end * _sink(v, bank), rel=1e-12)
    out = m.outputs(y, [[bank], [v]])
    assert out.roll[0] == -bank  # FLU roll = -bank: a left turn lowers the left wing
    gamma = math.asin(_sink(v, bank) / v)
    assert out.pitch[0] == pytest.approx(-gamma, rel=1e-12)
    assert out.omega[0] == pytest.approx(omega, rel=1e-12)
    # steady turn: no roll or pitch rate; the turn rate splits between body y and z
    p, q, r = out.rates[0]
    assert p == pytest.approx(-omega * math.sin(-gamma), abs=1e-12)
    assert q == pytest.approx(omega * math.sin(-bank) * math.cos(gamma), abs=1e-12)
    assert r == pytest.approx(omega * math.cos(bank) * math.cos(gamma), abs=1e-12)


def test_level_glide_pitch_is_the_sink_over_airspeed_ratio() -> None:
    # heading 0.3 rad, wings level, 10 m/s on the SB-XC polar: sink -0.4392 m/s, so the nose
    # is down by asin(0.4392 / 10) = 2.52 deg (docs/bus.md: "about 2.5 deg at 10 m/s")
    att = glide_attitude(0.3, 0.0, 10.0)
    gamma = math.asin(-_sink(10.0) / 10.0)
    assert _sink(10.0) == pytest.approx(-0.4392, abs=1e-12)
    assert float(att.pitch) == pytest.approx(gamma, rel=1e-14)
    assert math.degrees(gamma) == pytest.approx(2.52, abs=0.005)
    assert float(att.roll) == 0.0 and float(att.yaw) == pytest.approx(0.3, abs=1e-15)
    nose = quat_rotate(att.quat, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(nose, [math.cos(gamma) * math.cos(0.3),
                                      math.cos(gamma) * math.sin(0.3), -math.sin(gamma)],
                               atol=1e-15)
    # the same from the ratio given directly: 1 m/s down at 10 m/s is asin(0.1)
    assert float(attitude(0.0, 0.0, 10.0, -1.0).pitch) == pytest.approx(math.asin(0.1), 1e-15)
    # a vehicle holding its height, or not moving through the air, flies level
    assert float(attitude(0.0, 0.2, 10.0, 0.0).pitch) == 0.0
    assert float(attitude(0.0, 0.2, 0.0, -1.0).pitch) == 0.0


@pytest.mark.parametrize("bank", [0.3, -0.5])
def test_coordinated_turn_attitude_has_roll_minus_bank(bank: float) -> None:
    v = 12.0
    att = glide_attitude(math.pi / 2, bank, v)
    assert float(att.roll) == -bank  # docs/bus.md: a coordinated turn has roll = -bank
    gamma = math.asin(-_sink(v, bank) / v)
    assert float(att.pitch) == pytest.approx(gamma, rel=1e-14)
    # heading north, nose down by the glide angle; a left turn (bank > 0) lowers the left
    # wing (body +y), a right turn the right one
    nose = quat_rotate(att.quat, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(nose, [0.0, math.cos(gamma), -math.sin(gamma)], atol=1e-15)
    left = quat_rotate(att.quat, [0.0, 1.0, 0.0])
    assert left[2] == pytest.approx(-math.sin(bank) * math.cos(gamma), abs=1e-15)


def test_flight_model_attitude_is_the_one_derivation_and_ignores_the_updraft() -> None:
    m = FlightModel.from_params([FlightParams()] * 3, glide=[True, True, False], polar=POLAR)
    y = np.array([[0.0, 1.0, 2.0], [0.0] * 3, [500.0] * 3, [0.3, 2.0, -1.0],
                  [0.2, -0.4, 0.1], [9.0, 12.0, 10.0]])
    u = np.stack([y[BANK], y[SPEED]])
    still, lifted = m.outputs(y, u), m.outputs(y, u, np.array([2.5, 1.0, 2.5]))
    assert lifted.vz[0] == pytest.approx(still.vz[0] + 2.5, abs=1e-12)  # it climbs ...
    np.testing.assert_array_equal(lifted.quat, still.quat)  # ... without tilting
    glides = glide_attitude(y[HEADING, :2], y[BANK, :2], y[SPEED, :2], POLAR)
    np.testing.assert_array_equal(still.quat[:2], glides.quat)
    np.testing.assert_array_equal(still.quat[2], attitude(-1.0, 0.1, 10.0, 0.0).quat)
    # the default polar is the seed law's SB-XC
    np.testing.assert_allclose(glide_attitude(y[HEADING], y[BANK], y[SPEED]).quat[:2],
                               glides.quat, atol=0.0)
    # vectorised over any shape S: (2, 3) runs x vehicles as each alone
    h, b, v = (np.stack([y[r], y[r][::-1]]) for r in (HEADING, BANK, SPEED))
    grid = glide_attitude(h, b, v)
    assert grid.quat.shape == (2, 3, 4)
    np.testing.assert_array_equal(grid.quat[1, 0], glide_attitude(h[1, 0], b[1, 0], v[1, 0]).quat)


def test_bank_follows_a_rate_limited_first_order_lag() -> None:
    tau, pmax = 0.4, math.radians(70.0)
    m = _model(glide=False, bank_tau_s=tau, bank_rate_max=pmax)
    cmd = math.radians(60.0)
    # rate limited while the error exceeds pmax * tau, then exponential
    t_lin = (cmd - pmax * tau) / pmax
    for t in (0.2, t_lin, 1.0, 2.0):
        y, _ = m.step(_state(bank=0.0), [[cmd], [10.0]], t, substeps=2000)
        if t <= t_lin:
            expect = pmax * t
        else:
            expect = cmd - pmax * tau * math.exp(-(t - t_lin) / tau)
        assert y[BANK, 0] == pytest.approx(expect, abs=1e-8), t  # the kink: O(h^2)
    # airspeed: rate-limited at 1 m/s^2 while |error| > tau * rate = 5 m/s
    y, _ = m.step(_state(v=8.0), [[0.0], [9.0]], 3.0, substeps=300)
    assert y[SPEED, 0] == pytest.approx(9.0 - math.exp(-3.0 / 5.0), abs=1e-9)


def _reference(m: FlightModel, y0: np.ndarray, u: np.ndarray, t_end: float) -> np.ndarray:
    fun = m.fun(u)
    sol = solve_ivp(lambda t, y: fun(t, y.reshape(6, -1)).ravel(), (0.0, t_end), y0.ravel(),
                    method="DOP853", rtol=1e-13, atol=1e-12)
    assert sol.success
    return np.asarray(sol.y[:, -1].reshape(6, -1))


def test_error_falls_as_dt_to_the_fourth_where_the_dynamics_are_smooth() -> None:
    m = _model(bank_tau_s=0.5, bank_rate_max=10.0)  # the rate limit never acts: smooth
    y0, u = _state(bank=0.0, v=10.0), np.array([[0.4], [11.0]])
    ref = _reference(m, y0, u, 10.0)
    errors = []
    for h in (0.1, 0.05, 0.025, 0.0125):
        y, _ = m.step(y0, u, 10.0, substeps=round(10.0 / h))
        errors.append(float(np.max(np.abs(y - ref)[:3])))
    orders = [math.log2(a / b) for a, b in itertools.pairwise(errors)]
    assert errors[-1] < 1e-8
    assert all(3.8 < o < 4.4 for o in orders), (errors, orders)


def test_error_still_converges_across_the_rate_limit() -> None:
    m = _model()  # defaults: a 0.5 rad step hits the 70 deg/s bank rate limit
    y0, u = _state(), np.array([[-0.5], [12.0]])
    ref = _reference(m, y0, u, 10.0)
    errors = []
    for h in (0.1, 0.05, 0.025, 0.0125):
        y, _ = m.step(y0, u, 10.0, substeps=round(10.0 / h))
        errors.append(float(np.max(np.abs(y - ref)[:3])))
    # where a limit starts to act the rhs has a kink: second order overall, not fourth
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < errors[0] / 2**6 and errors[-1] < 1e-4, errors


def test_quaternion_euler_and_body_rates_agree() -> None:
    m = _model()
    y0 = np.array([[0.0, 5.0], [0.0, 1.0], [500.0, 800.0], [0.3, -2.0], [0.1, -0.3],
                   [9.0, 12.5]])
    u = np.array([[0.25, 0.2], [12.0, 9.0]])
    out = m.outputs(y0, u)
    np.testing.assert_allclose(out.quat, quat_from_euler(out.roll, out.pitch, out.yaw),
                               atol=1e-15)
    back = np.stack(euler_from_quat(out.quat))
    np.testing.assert_allclose(back, np.stack([out.roll, out.pitch, out.yaw]), atol=1e-12)
    # the analytic body rates are the rates the attitude actually turns at
    h = 1e-5
    y_plus, _ = m.step(y0, u, h)
    later = m.outputs(y_plus, u)
    numeric = body_rates_from_quats(out.quat, later.quat, h)
    np.testing.assert_allclose(numeric, out.rates, atol=2e-5)
    assert np.all(np.abs(out.rates[:, 0]) > 0.1)  # the bank is moving: a real roll rate


def test_vectorised_states_fly_as_each_alone() -> None:
    params = [FlightParams(), FlightParams(bank_tau_s=0.7, speed_rate_max=0.5)]
    m = FlightModel.from_params(params, glide=[True, False], polar=POLAR)
    y0 = np.array([[0.0, 5.0], [0.0, 1.0], [500.0, 800.0], [0.3, -2.0], [0.1, -0.3],
                   [9.0, 12.5]])
    u = np.array([[0.25, -0.2], [12.0, 9.0]])
    both, _ = m.step(y0, u, 3.0, substeps=30)
    for i, p in enumerate(params):
        alone = FlightModel.from_params([p], glide=[i == 0], polar=POLAR)
        one, _ = alone.step(y0[:, i : i + 1], u[:, i : i + 1], 3.0, substeps=30)
        np.testing.assert_array_equal(one[:, 0], both[:, i])
    assert both[Z, 1] == 800.0  # 'hold' keeps its height


def test_height_limits_ground_ceiling_and_floor() -> None:
    m = FlightModel.from_params([FlightParams()] * 3, glide=[True] * 3, polar=POLAR,
                                ceiling=1000.0, floor=np.array([0.0, 0.0, 50.0]))
    y0 = np.array([[0.0] * 3, [0.0] * 3, [0.3, 999.9, 50.5], [0.0] * 3, [0.0] * 3,
                   [10.0] * 3])
    w = np.array([0.0, 5.0, 0.0])
    y, grounded = m.step(y0, [[0.0] * 3, [10.0] * 3], 2.0, substeps=20,
                         updraft=lambda xy: w)
    assert grounded.tolist() == [True, False, False]
    assert 0.0 < y[Z, 0] <= 0.3 and y[X, 0] < 20.0  # stopped where it was before touching
    assert y[Z, 1] == 1000.0  # held at the ceiling
    assert y[Z, 2] == 50.0  # held at the floor: above z = 0 it never dies
    again, g2 = m.step(y, [[0.0] * 3, [10.0] * 3], 1.0, active=~grounded)
    np.testing.assert_array_equal(again[:, 0], y[:, 0])
    assert not g2.any()


def test_params_are_validated_and_long_steps_are_refined() -> None:
    with pytest.raises(ValueError, match="bank_tau_s"):
        FlightParams(bank_tau_s=0.0)
    with pytest.raises(ValueError, match="vertical"):
        FlightParams(vertical="climb")  # type: ignore[arg-type]
    m = _model()
    assert m.max_substep == pytest.approx(0.2)
    y0, u = _state(), np.array([[0.5], [12.0]])
    coarse, _ = m.step(y0, u, 2.0, substeps=1)  # refined to 10 sub-steps of 0.2 s
    fine, _ = m.step(y0, u, 2.0, substeps=10)
    np.testing.assert_array_equal(coarse, fine)


def test_a_path_flies_the_attitude_it_implies_or_the_one_it_logged() -> None:
    from sim_core.flight import path_state
    from sim_core.trajectory import Trajectory

    speed, radius = 4.0, 4.0**2 / (9.81 * math.tan(math.radians(30.0)))
    a = np.linspace(0.0, 2 * np.pi, 361)
    xyz = np.stack([radius * np.cos(a), radius * np.sin(a), np.full(a.shape, 2.0)], axis=1)
    circle = Trajectory.from_path(xyz, None, speed_mps=speed)
    ps = path_state(circle, 1.0)
    assert ps.bank == pytest.approx(math.radians(30.0), abs=math.radians(0.2))
    assert float(ps.outputs.roll) == -ps.bank and float(ps.outputs.pitch) == 0.0
    np.testing.assert_allclose(np.linalg.norm(ps.velocity[:2]), speed, rtol=1e-3)
    # a logged attitude (e.g. read from a flight log) wins over the implied one
    q = quat_from_euler(0.2, -0.1, np.linspace(0.0, 1.0, len(circle)))
    logged = Trajectory(circle.t, circle.xyz, circle.heading, circle.bank, circle.airspeed,
                        quat=q)
    lp = path_state(logged, 1.0)
    np.testing.assert_allclose(lp.outputs.quat, logged.attitude(1.0), atol=1e-12)
    assert float(lp.outputs.roll) == pytest.approx(0.2, abs=1e-9)
    assert float(lp.outputs.pitch) == pytest.approx(-0.1, abs=1e-9)
    assert lp.position.tolist() == ps.position.tolist()


def test_vehicles_on_paths_at_once_are_each_vehicle_alone() -> None:
    from sim_core.flight import path_state, path_states
    from sim_core.trajectory import Trajectory

    a = np.linspace(0.0, 2 * np.pi, 181)
    circle = Trajectory.from_path(np.stack([5 * np.cos(a), 5 * np.sin(a), 2 + 0.1 * a], axis=1),
                                  None, speed_mps=3.0)
    line = Trajectory(np.array([0.0, 4.0]), np.array([[0.0, 0, 1], [8.0, 0, 3]]),
                      np.zeros(2), np.zeros(2), np.full(2, 2.0), loop=False)
    logged = Trajectory(circle.t, circle.xyz, circle.heading, circle.bank, circle.airspeed,
                        quat=quat_from_euler(0.2, -0.1, np.linspace(0.0, 1.0, len(circle))))
    trajs = [circle, line, logged]
    for t in (0.0, 1.37, 3.999, 50.0):
        many = path_states(trajs, t)
        for v, traj in enumerate(trajs):
            one = path_state(traj, t)
            np.testing.assert_array_equal(many.position[v], one.position)
            np.testing.assert_array_equal(many.velocity[v], one.velocity)
            assert (many.heading[v], many.bank[v], many.airspeed[v]) == (
                one.heading, one.bank, one.airspeed)
            for field in ("vz", "omega", "roll", "pitch", "yaw", "quat", "rates"):
                np.testing.assert_array_equal(getattr(many.outputs, field)[v],
                                              getattr(one.outputs, field))
