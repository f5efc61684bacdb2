"""Closed-form checks of the thermal, glider and controller physics (seed 002 §3)."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import quad

from sim_core.soaring import Commands, Law, SwarmSim, law_params, run, sink_rate, updraft
from sim_core.soaring.boids import boids_accel
from sim_core.soaring.thermals import spawn_thermals

QUIET = {"cohesion": 0.0, "separation": 0.0, "alignment": 0.0, "migration": 0.0, "waggle": 0.0}


def _lone(**kw: object) -> Law:
    base = {"numThermals": 0, "agents": [{"x": 0.0, "y": 0.0, "z": 1500.0, "heading": 0.0,
                                          "speed": 10.0}], **QUIET}
    base.update(kw)
    return Law().replace(**base)


def test_polar_minimum_sink() -> None:
    v = np.linspace(8, 13, 5001)
    s = sink_rate(v, 0.0, -0.01843, 0.3782, -2.3782)
    i = int(np.argmax(s))
    assert abs(v[i] - 10.26) < 0.01 and abs(s[i] + 0.438) < 1e-3
    assert abs(sink_rate(10.0, math.radians(60), -0.01843, 0.3782, -2.3782)
               - sink_rate(10.0, 0.0, -0.01843, 0.3782, -2.3782) * math.sqrt(2)) < 1e-12


def test_straight_glide_with_zero_gains_sinks_at_polar_rate() -> None:
    law = _lone(totalTime=100.0)
    r = run(law, trace=True)
    tr = r.trace
    assert tr is not None
    expected = float(sink_rate(10.0, 0.0, law.Sink_A, law.Sink_B, law.Sink_C))
    assert np.all(tr.vz[1:, 0] == expected)
    assert np.allclose(tr.z[:, 0], 1500.0 + expected * tr.t, rtol=0, atol=1e-9)
    assert np.all(tr.heading[:, 0] == 0.0) and np.all(tr.bank[:, 0] == 0.0)
    assert np.allclose(tr.x[:, 0], 10.0 * tr.t, rtol=0, atol=1e-9)


def test_crossing_a_pinned_thermal_gains_the_integral_of_the_profile() -> None:
    W, R, v, dt = 5.0, 400.0, 10.0, 0.02
    law = _lone(dt=dt, totalTime=100.0, thermals=[{"x": 500.0, "y": 30.0, "radius": R,
                                                    "strength": W, "fade": False}])
    r = run(law, trace=True)
    tr = r.trace
    assert tr is not None
    sink = float(sink_rate(v, 0.0, law.Sink_A, law.Sink_B, law.Sink_C))
    gain = tr.z[-1, 0] - tr.z[0, 0] - sink * law.totalTime
    th = spawn_thermals(law, np.random.default_rng(0))
    # exactly the per-step sum of the profile at the positions flown (left Riemann sum)
    xy = np.column_stack([tr.x[:-1, 0], tr.y[:-1, 0]])
    assert math.isclose(gain, float(np.sum(updraft(xy, th) * dt)), rel_tol=1e-9)

    # and the continuous integral of w along the chord, to O(dt)
    def w_at(x: float) -> float:
        d = math.hypot(x - 500.0, 30.0)
        u = (3 * d / R) ** 2
        return W * math.exp(-u) * (1 - u) if d < R else 0.0

    half = math.sqrt(R**2 - 30.0**2)
    integral, _ = quad(w_at, 500.0 - half, 500.0 + half, points=[500.0], limit=200)
    assert math.isclose(gain, integral / v, rel_tol=0, abs_tol=W * dt * 2)
    assert gain > 0


def test_profile_shape_and_first_thermal_wins() -> None:
    th = spawn_thermals(Law(thermals=None).replace(thermals=[
        {"x": 0.0, "y": 0.0, "radius": 300.0, "strength": 4.0},
        {"x": 100.0, "y": 0.0, "radius": 300.0, "strength": 9.0},
    ]), np.random.default_rng(0))
    R = 300.0
    d_min = math.sqrt(2) * R / 3
    pts = [[0.0, 0.0], [-d_min, 0.0], [-R / 3, 0.0], [0.0, 299.999], [0, 300.0]]
    w = updraft(np.array(pts), th)
    assert w[0] == 4.0  # first thermal wins over the stronger second one
    assert math.isclose(w[1], -4.0 * math.exp(-2), rel_tol=1e-12)
    assert abs(w[2]) < 1e-12
    assert w[3] < 0 and w[4] == 0.0


def test_steady_turn_radius() -> None:
    v, phi, dt = 10.0, math.radians(15), 0.01
    law = _lone(dt=dt, totalTime=30.0)
    sim = SwarmSim(law, seed=0)
    xs, ys = [], []
    cmd = Commands(np.array([[phi]]), np.array([[v]]), np.array([[True]]))
    for _ in range(law.steps):
        sim.step(cmd)
        s = sim.state
        xs.append(s.x[0, 0])
        ys.append(s.y[0, 0])
    x, y = np.array(xs), np.array(ys)
    A = np.column_stack([x, y, np.ones_like(x)])
    cx, cy, c = np.linalg.lstsq(A, x**2 + y**2, rcond=None)[0]
    radius = math.sqrt(c / 1 + (cx / 2) ** 2 + (cy / 2) ** 2)
    expected = v**2 / (9.81 * math.tan(phi))
    assert math.isclose(radius, expected, rel_tol=1e-4)


def test_rate_limits_slew_bank_and_speed() -> None:
    law = _lone(dt=0.5, totalTime=5.0, bankRateMax=0.1, speedRateMax=0.2, forwardSpeedMax=13.0)
    sim = SwarmSim(law, seed=0)
    sim.step(Commands(np.array([[0.25]]), np.array([[13.0]]), np.array([[True]])))
    s = sim.state
    assert math.isclose(s.bank[0, 0], 0.05) and math.isclose(s.speed[0, 0], 10.1)


def test_no_neighbours_only_migration_acts() -> None:
    law = Law().replace(cohesion=1e5, separation=10.0, alignment=1.0, migration=1e-21)
    P = law_params([law])
    own = {k: np.array([[val]]) for k, val in
           {"x": 1200.0, "y": -700.0, "z": 900.0, "heading": 0.4, "speed": 11.0,
            "vz": -0.5}.items()}
    nb = {k: np.zeros(0) for k in ("x", "y", "z", "vx", "vy", "vz")}
    acc = boids_accel(own, nb, np.zeros(0, dtype=np.intp), P, np.zeros((1, 1)))
    d = math.hypot(1200.0, 700.0)
    assert math.isclose(acc.ax[0, 0], -1200.0 * d**5 * 1e-21, rel_tol=1e-12)
    assert math.isclose(acc.ay[0, 0], 700.0 * d**5 * 1e-21, rel_tol=1e-12)
    # a lone glider flies the same with or without the neighbour gains
    lone = {"numThermals": 0, "numAgents": 1, "totalTime": 300.0}
    a = run(law.replace(**lone), trace=True).trace
    b = run(law.replace(cohesion=0.0, separation=0.0, alignment=0.0, **lone), trace=True).trace
    assert a is not None and b is not None
    assert np.array_equal(a.x, b.x) and np.array_equal(a.heading, b.heading)
    assert not np.all(a.bank == 0.0)


def test_fade_cycle_plateaus_in_steps_and_in_seconds() -> None:
    pinned = [{"x": 0.0, "y": 0.0, "radius": 300.0, "strength": 4.0, "fade": True}]
    law = _lone(totalTime=1000.0, thermals=pinned, agents=[])
    sim = SwarmSim(law, seed=0)
    w = []
    for _ in range(law.steps):
        sim.step()
        w.append(sim.thermals.strength[0, 0])
    w_arr = np.array(w)
    top = int(np.argmax(w_arr < 4.0))
    assert top == 600  # 601 steps on the top plateau (steps 1..601), then 0.005 per step
    assert math.isclose(w_arr[top], 4.0 - 0.005, rel_tol=1e-12)
    # time-based fade: the same cycle at dt 0.25 in seconds as the seed's at dt 0.5
    lt = law.replace(dt=0.25, thermalFadeMode="seconds")
    sim2 = SwarmSim(lt, seed=0)
    w2 = []
    for _ in range(lt.steps):
        sim2.step()
        w2.append(sim2.thermals.strength[0, 0])
    w2_arr = np.array(w2)[1::2]
    assert np.allclose(w2_arr[:1500], w_arr[:1500], atol=0.006)
