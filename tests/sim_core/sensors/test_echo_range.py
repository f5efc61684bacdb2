"""The echo → range rule against the echo model on closed-form scenes: a flat ground of leaves
at a known height below the sonar, and one leaf at a known range."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_core.sensors import RangeRule, echo_ranges
from sim_core.sensors.echo_range import _analytic_bins, _coarse_envelope
from sim_core.sonar import Beam, EchoParams, synthesize, to_baseband
from sim_core.sonar.params import Ear


def ground(half: float = 4.0, step: float = 0.03, radius: float = 0.012,
           seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat ground at z = 0: leaves of 12 mm facing up on a jittered 3 cm grid."""
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g)
    c = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    c[:, :2] += np.random.default_rng(seed).uniform(-step / 2, step / 2, (len(c), 2))
    return c, np.tile([0.0, 0.0, 1.0], (len(c), 1)), np.full(len(c), radius)


GROUND = ground()


@pytest.mark.parametrize("height", [0.5, 1.0, 2.0, 4.0, 7.0, 9.5])
def test_a_flat_ground_below_is_ranged_at_its_height(height: float) -> None:
    """The first return of the ground is its nearest point: within 2 cm above the height
    (the first return's peak gathers the leaves of the first Fresnel zone; measured: -1.3 mm
    to +17 mm over these heights), never below it by more than 2 mm."""
    echo = synthesize(GROUND, Beam([0.0, 0.0, height], [0.0, 0.0, -1.0], 0.7), EchoParams(),
                      fidelity="fast")
    r = echo_ranges(echo.samples, echo.fs)
    assert -0.002 <= r.range_m[0] - height <= 0.02
    assert r.margin_db[0] > 10.0
    assert r.window_m == pytest.approx(10.2)


@pytest.mark.parametrize("distance", [0.7, 1.234, 3.3, 6.66, 9.0])
def test_an_isolated_leaf_is_ranged_at_its_distance(distance: float) -> None:
    """A point scatterer's envelope peaks at its delay 2r/v: the rule is exact to 1 µm."""
    leaf = (np.array([[distance, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([0.02]))
    echo = synthesize(leaf, Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.7), EchoParams(),
                      fidelity="reference")
    assert echo_ranges(echo.samples, echo.fs).range_m[0] == pytest.approx(distance, abs=1e-6)


@pytest.mark.parametrize("centre", [400, 420, 435, 441, 460])
def test_a_return_inside_the_blind_zone_is_not_ranged_before_its_edge(centre: int) -> None:
    """A pulse centred inside the blind zone (0.2 m: sample 471 at 400 kHz) still falls,
    concave, at the zone's edge. The rule may report that edge (a return too close: the
    messages say so), never a time more than one coarse step before it (the coarse peak's
    parabola is taken only at a coarse peak, not extrapolated back into the zone)."""
    fs, n = 4e5, 24000
    k = np.arange(n)
    x = np.exp(-0.5 * ((k - centre) / 60.0) ** 2) * np.cos(2 * np.pi * 7e4 / fs * k) * 1e-3
    rule = RangeRule(min_range_m=0.2)
    bins, spec = _analytic_bins(x[None], False)
    step = _coarse_envelope(bins, spec, n)[0]
    edge = math.ceil(2.0 * 0.2 / 340.0 * fs)
    r = echo_ranges(x, fs, rule).range_m[0]
    assert r >= 340.0 * (edge - step) / fs / 2.0


def test_single_and_double_precision_samples_range_alike() -> None:
    """Single-precision samples (as the server publishes them) keep the bins above 2e-6 of the
    largest, double 1e-7: the same return, to a micrometre."""
    leaf = (np.array([[0.0, 0.0, -3.1]]), np.array([[0.0, 0.0, 1.0]]), np.array([0.02]))
    echo = synthesize(leaf, Beam([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 0.7), EchoParams(),
                      fidelity="reference")
    double = echo_ranges(echo.samples.astype(np.float64), echo.fs).range_m
    single = echo_ranges(echo.samples.astype(np.float32), echo.fs).range_m
    np.testing.assert_allclose(single, double, atol=1e-6)


def test_each_ear_is_ranged_and_baseband_agrees() -> None:
    """Two ears 10 cm apart across the beam hear the ground leaf at their own path lengths;
    the complex baseband of the same echo gives the same ranges to a tenth of its resolution
    (20 kHz: 8.5 mm)."""
    leaf = (np.array([[0.0, 0.0, -2.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([0.02]))
    ears = (Ear(offset=(0.0, 0.05, 0.0)), Ear(offset=(0.0, -0.05, 0.0)))
    echo = synthesize(leaf, Beam([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 0.7),
                      EchoParams(ears=ears), fidelity="reference")
    r = echo_ranges(echo.samples, echo.fs)
    expect = (2.0 + math.hypot(2.0, 0.05)) / 2.0  # emitter to leaf to ear, halved
    np.testing.assert_allclose(r.range_m, expect, atol=1e-6)
    iq, fs_iq = to_baseband(echo.samples, echo.fs, 70e3, 20)
    np.testing.assert_allclose(echo_ranges(iq, fs_iq).range_m, expect, atol=0.1 * 340 / 2e4 / 2)


def test_no_return_and_a_return_below_the_threshold_are_nan() -> None:
    quiet = echo_ranges(np.zeros((2, 24000)), 4e5)
    assert np.isnan(quiet.range_m).all() and np.isnan(quiet.level_db).all()
    leaf = (np.array([[8.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([0.01]))
    echo = synthesize(leaf, Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.7), EchoParams())
    level = float(echo_ranges(echo.samples, echo.fs).level_db[0])
    deaf = RangeRule(threshold_db=level + 1.0)
    assert np.isnan(echo_ranges(echo.samples, echo.fs, deaf).range_m[0])
    blind = RangeRule(min_range_m=8.5)
    assert np.isnan(echo_ranges(echo.samples, echo.fs, blind).range_m[0])
    assert np.isnan(echo_ranges(np.full(100, np.nan), 4e5).range_m[0])


@settings(max_examples=40, deadline=None)
@given(st.floats(0.2, 7.0), st.floats(-40.0, -1.0), st.floats(0.5, 3.0))
def test_the_first_of_two_returns_is_reported(first: float, weaker_db: float,
                                              gap_m: float) -> None:
    """Two band-limited returns (the model's pulse: a Hann-windowed 60-80 kHz band): the nearer
    one is reported, at its range, whenever it is above the detection level, even when the
    farther one is louder; it is missed only when more than |relative_db| below the loudest."""
    params = EchoParams()
    second = first + gap_m  # at least 0.5 m apart: far beyond the pulse's envelope
    n, fs = params.samples, params.fs
    spectrum = np.zeros(n // 2 + 1, complex)
    k = np.arange(round(params.f_lo * n / fs), round(params.f_hi * n / fs) + 1)
    w = 0.5 * (1 - np.cos(2 * np.pi * np.arange(len(k)) / len(k)))
    for r, amp in ((first, 10 ** (weaker_db / 20)), (second, 1.0)):
        spectrum[k] += amp * w * np.exp(-2j * np.pi * k * fs / n * 2 * r / 340.0)
    x = np.fft.irfft(spectrum, n)  # peaks near -26 dB re A0: both above -100 dB
    got = echo_ranges(x, fs).range_m[0]
    if weaker_db >= -24.0:  # the other pulse's tails move the peak by well under 0.1 mm
        assert got == pytest.approx(first, abs=1e-4)
    elif weaker_db < -26.0:
        assert got == pytest.approx(second, abs=1e-4)
