"""The sensor suite: the truth exactly without noise, noise of the stated size with it, the
same bits for the same seed, and GNSS fixes at their rate, late by their latency."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_core.pose import quat_conjugate, quat_from_euler, quat_rotate
from sim_core.sensors import (
    GpsSpec,
    SensorSpec,
    SensorSuite,
    SensorTruth,
    dynamic_pressure,
    field_enu,
    isa,
)

TICK_NS = 4_000_000  # 250 Hz


def truth(t_s: float = 0.0, n: int = 2) -> SensorTruth:
    """N gliders flying east at 20 m/s, sinking 0.7 m/s, banked and pitched differently."""
    q = quat_from_euler(np.linspace(-0.4, 0.3, n), np.linspace(0.05, 0.1, n), np.zeros(n))
    lat0 = np.linspace(47.0, 47.01, n)
    lon = 8.0 + 20.0 * t_s / (6.371e6 * math.cos(math.radians(47.0))) * 180 / math.pi
    return SensorTruth.of(
        geodetic=np.column_stack([lat0, np.full(n, lon), np.full(n, 400.0 - 0.7 * t_s)]),
        velocity=np.tile([20.0, 0.0, -0.7], (n, 1)), quat=q,
        rates=np.tile([0.01, -0.02, 0.03], (n, 1)),
        specific_force=quat_rotate(quat_conjugate(q), np.array([0.0, 0.0, 9.80665])),
        airspeed=np.full(n, 20.0))


def test_without_noise_the_readings_are_the_truth() -> None:
    suite = SensorSuite(SensorSpec(noise=False), 2)
    tr = truth()
    r = suite.sample(0, tr)
    assert np.array_equal(r.accel, tr.specific_force)
    assert np.array_equal(r.gyro, tr.rates)
    p, t, rho = isa(tr.geodetic[:, 2])
    np.testing.assert_allclose(r.abs_pressure, p, rtol=1e-15)
    np.testing.assert_allclose(r.temperature, t - 273.15, rtol=1e-15)
    np.testing.assert_allclose(r.diff_pressure, dynamic_pressure(rho, 20.0), rtol=1e-15)
    b = field_enu(tr.geodetic[:, 0], tr.geodetic[:, 1], tr.geodetic[:, 2], 2026.0)
    np.testing.assert_allclose(r.mag, quat_rotate(quat_conjugate(tr.quat), b), atol=1e-15)
    # the body field has the field's size whatever the attitude
    np.testing.assert_allclose(np.linalg.norm(r.mag, axis=1), np.linalg.norm(b, axis=1),
                               rtol=1e-12)


def test_white_noise_has_the_stated_density() -> None:
    """One sample's standard deviation is density · sqrt(rate): at 250 Hz, 4.0e-3 m/s²/√Hz is
    0.063 m/s² and 3.394e-4 rad/s/√Hz is 5.37e-3 rad/s (biases removed by differencing)."""
    spec = SensorSpec()
    suite = SensorSuite(spec, 1, seed=3)
    tr = truth(n=1)
    acc, gyr, mag, baro = [], [], [], []
    for k in range(10000):
        r = suite.sample(k * TICK_NS, tr)
        acc.append(r.accel[0] - tr.specific_force[0])
        gyr.append(r.gyro[0] - tr.rates[0])
        mag.append(r.mag[0])
        baro.append(r.abs_pressure[0])
    rate = 250.0
    # successive differences of white noise plus a slow walk: variance 2 sigma^2
    for series, density in ((acc, spec.imu.accel_noise_density),
                            (gyr, spec.imu.gyro_noise_density),
                            (mag, spec.mag.noise_density)):
        d = np.diff(np.array(series), axis=0)
        sigma = d.std(axis=0) / math.sqrt(2.0)
        np.testing.assert_allclose(sigma, density * math.sqrt(rate), rtol=0.04)
    assert np.diff(baro).std() / math.sqrt(2.0) == pytest.approx(spec.baro_noise_pa, rel=0.04)
    # the bias wanders as a random walk: after 40 s about 6.0e-3 · sqrt(40) = 0.038 m/s²
    walk = np.array(acc[-2000:]).mean(axis=0)
    assert np.all(np.abs(walk) < 5 * spec.imu.accel_random_walk * math.sqrt(40.0))


def test_the_same_seed_gives_the_same_bits_and_another_seed_does_not() -> None:
    def run(seed: int) -> list[np.ndarray]:
        suite = SensorSuite(SensorSpec(), 2, seed=seed, key=(7,))
        out = []
        for k in range(300):
            r = suite.sample(k * TICK_NS, truth(k * 0.004))
            fix = suite.gps_fix(k * TICK_NS)
            out += [r.accel, r.gyro, r.mag, r.abs_pressure, r.diff_pressure]
            if fix is not None:
                out += [fix.lat_deg, fix.lon_deg, fix.alt_m, fix.velocity]
        return out

    a, b, c = run(5), run(5), run(6)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c, strict=True))


def test_gps_fixes_come_at_their_rate_late_by_their_latency() -> None:
    spec = SensorSpec(noise=False, gps=GpsSpec(rate_hz=10.0, latency_s=0.1))
    suite = SensorSuite(spec, 2)
    fixes = []
    for k in range(1000):  # 4 s at 250 Hz
        t_s = k * 0.004
        suite.sample(k * TICK_NS, truth(t_s))
        fix = suite.gps_fix(k * TICK_NS)
        if fix is not None:
            fixes.append(fix)
    assert len(fixes) == 40
    assert [f.t_ns for f in fixes] == [k * 100_000_000 for k in range(40)]
    for f in fixes[2:]:
        late = truth((f.t_ns - 100_000_000) / 1e9)
        assert f.measured_ns == f.t_ns - 100_000_000
        np.testing.assert_allclose(f.lon_deg, late.geodetic[:, 1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.alt_m, late.geodetic[:, 2], rtol=0, atol=1e-9)
    # before the latency has passed, the oldest truth stands in
    np.testing.assert_allclose(fixes[0].lon_deg, truth(0.0).geodetic[:, 1], atol=1e-12)


def test_gps_noise_is_of_the_stated_size() -> None:
    spec = SensorSpec(gps=GpsSpec(drift_sigma_m=0.0, horizontal_sigma_m=0.3,
                                  vertical_sigma_m=0.5, velocity_sigma_mps=0.05))
    suite = SensorSuite(spec, 1, seed=11)
    tr = SensorTruth.of(geodetic=np.array([[47.0, 8.0, 400.0]]), velocity=np.zeros((1, 3)),
                     quat=np.array([[1.0, 0, 0, 0]]), rates=np.zeros((1, 3)),
                     specific_force=np.array([[0, 0, 9.8]]), airspeed=np.array([20.0]))
    north, up, vel = [], [], []
    for k in range(3000):  # sampled at the fixes' rate: every sample is a fix
        suite.sample(k * 100_000_000, tr)
        fix = suite.gps_fix(k * 100_000_000)
        if fix is not None:
            north.append((fix.lat_deg[0] - 47.0) * math.pi / 180 * 6.367e6)
            up.append(fix.alt_m[0] - 400.0)
            vel.append(fix.velocity[0, 0])
    assert np.std(north) == pytest.approx(0.3, rel=0.06)
    assert np.std(up) == pytest.approx(0.5, rel=0.06)
    assert np.std(vel) == pytest.approx(0.05, rel=0.06)


def test_bad_specs_name_the_key() -> None:
    with pytest.raises(ValueError, match="rate_hz"):
        GpsSpec(rate_hz=0.0)
    with pytest.raises(ValueError, match="latency_s"):
        GpsSpec(latency_s=2.0)
    with pytest.raises(ValueError, match="baro_noise_pa"):
        SensorSpec(baro_noise_pa=-1.0)
