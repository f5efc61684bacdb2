"""The reference fidelity against closed forms and the guards of docs/spec/echo_model.md."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_core.sonar import Beam, EchoParams, synthesize
from tests.sim_core.sonar._scenes import FS, V, cone_cloud, envelope, rel_l2, single_leaf_peak

ON_AXIS = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(30.0))


def one_leaf(r: float, a: float = 0.025, normal: tuple[float, ...] = (-1.0, 0.0, 0.0)) -> tuple:
    return (np.array([[r, 0.0, 0.0]]), np.array([normal]), np.array([a]))


@pytest.mark.parametrize("fidelity", ["reference", "fast"])
def test_single_leaf_on_axis_pulse_at_two_r_over_v_with_predicted_amplitude(fidelity: str) -> None:
    n0 = 7000  # r chosen so 2r/v falls on sample n0
    r = n0 / FS * V / 2.0
    echo = synthesize(one_leaf(r), ON_AXIS, fidelity=fidelity)
    env = envelope(echo.samples)
    assert int(np.argmax(env)) == n0
    expected = single_leaf_peak(r, 0.025, 0.0)
    assert env[n0] == pytest.approx(expected, rel=1e-9 if fidelity == "reference" else 1e-4)
    assert echo.leaves_in_beam == 1 and echo.dropped == 0


def test_moving_leaf_by_dr_shifts_pulse_by_two_dr_over_v() -> None:
    r = 7000 / FS * V / 2.0
    dr = 850 / FS * V / 2.0  # 850-sample shift
    e1 = envelope(synthesize(one_leaf(r), ON_AXIS, fidelity="reference").samples)
    e2 = envelope(synthesize(one_leaf(r + dr), ON_AXIS, fidelity="reference").samples)
    assert int(np.argmax(e2)) - int(np.argmax(e1)) == round(2 * dr / V * FS) == 850
    np.testing.assert_allclose(np.roll(e1, 850)[7500:8500], e2[7500:8500] * 1.0, rtol=0.5)


def test_doubling_r_with_spreading_divides_peak_by_four() -> None:
    r = 5000 / FS * V / 2.0
    p1 = envelope(synthesize(one_leaf(r), ON_AXIS, fidelity="reference").samples).max()
    p2 = envelope(synthesize(one_leaf(2 * r), ON_AXIS, fidelity="reference").samples).max()
    assert p1 / p2 == pytest.approx(4.0, rel=1e-9)
    flat = EchoParams(spreading=False)
    q1 = envelope(synthesize(one_leaf(r), ON_AXIS, flat, fidelity="reference").samples).max()
    q2 = envelope(synthesize(one_leaf(2 * r), ON_AXIS, flat, fidelity="reference").samples).max()
    assert q1 / q2 == pytest.approx(1.0, rel=1e-9)


def test_leaves_all_at_one_range_sum_coherently() -> None:
    r = 6000 / FS * V / 2.0
    ang = np.radians([0.0, 1.0, 2.0, 3.0])
    centers = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros(4)], 1)
    normals = -centers
    radii = np.full(4, 0.025)
    total = synthesize((centers, normals, radii), ON_AXIS, fidelity="reference").samples
    parts = sum(
        synthesize((centers[i : i + 1], normals[i : i + 1], radii[i : i + 1]), ON_AXIS,
                   fidelity="reference").samples
        for i in range(4)
    )
    np.testing.assert_allclose(total, parts, atol=1e-12 * np.abs(total).max())
    beam_gain = np.exp(-(ang**2) / (2 * ON_AXIS.sigma**2)) ** 2
    peak = envelope(total).max()
    assert peak == pytest.approx(single_leaf_peak(r, 0.025, 0.0) * beam_gain.sum(), rel=1e-6)


def test_guards_drop_and_count_invalid_leaves() -> None:
    centers = np.array(
        [[2.0, 0, 0], [np.nan, 0, 0], [3.0, 0, 0], [0.05, 0, 0], [4.0, 0, 0], [2.5, 0.0, 0.0]]
    )
    normals = np.array(
        [[1.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [1.0, np.inf, 0], [1.0, 0, 0]]
    )
    radii = np.array([0.02, 0.02, 0.02, 0.02, 0.02, np.nan])
    echo = synthesize((centers, normals, radii), ON_AXIS, fidelity="reference")
    assert echo.dropped == 5  # nan centre, zero normal, r < r_min, inf normal, nan radius
    assert echo.leaves_in_beam == 1
    assert np.all(np.isfinite(echo.samples))


def test_no_leaves_gives_all_zero_echo() -> None:
    empty = (np.empty((0, 3)), np.empty((0, 3)), np.empty(0))
    for fid in ("reference", "fast", "realtime"):
        echo = synthesize(empty, ON_AXIS, fidelity=fid)
        assert echo.samples.shape == (24000,) and not echo.samples.any()
        assert echo.leaves_in_beam == 0


@pytest.mark.parametrize("bw_deg", [0.0, -1.0, 180.0, 200.0, math.nan])
def test_beamwidth_outside_open_interval_is_rejected(bw_deg: float) -> None:
    with pytest.raises(ValueError, match="beamwidth"):
        Beam([0, 0, 0], [1, 0, 0], math.radians(bw_deg))


def test_window_too_short_for_farthest_leaf_is_rejected() -> None:
    params = EchoParams(samples=12000)  # 30 ms holds 5.1 m
    with pytest.raises(ValueError, match="cannot hold the farthest kept leaf"):
        synthesize(one_leaf(6.0), ON_AXIS, params, fidelity="reference")
    assert synthesize(one_leaf(4.0), ON_AXIS, params).leaves_in_beam == 1


def test_non_integer_band_edges_are_rejected() -> None:
    with pytest.raises(ValueError, match="not a multiple of the bin spacing"):
        EchoParams(samples=24001)
    with pytest.raises(ValueError, match="Nyquist"):
        EchoParams(fs=150e3, samples=24000, f_hi=80e3)


def test_selection_is_the_waterdrop() -> None:
    # on axis, kept up to 10 m; at the -3 dB edge (S1 = 0.7079) up to 7.079 m
    half = ON_AXIS.beamwidth_rad / 2
    inside = (7.0 * np.array([[math.cos(half), math.sin(half), 0.0]]), np.array([[1.0, 0, 0]]),
              np.array([0.02]))
    outside = (7.2 * np.array([[math.cos(half), math.sin(half), 0.0]]), np.array([[1.0, 0, 0]]),
               np.array([0.02]))
    assert synthesize(inside, ON_AXIS, fidelity="reference").leaves_in_beam == 1
    assert synthesize(outside, ON_AXIS, fidelity="reference").leaves_in_beam == 0
    assert synthesize(one_leaf(9.99), ON_AXIS).leaves_in_beam == 1
    assert synthesize(one_leaf(10.01), ON_AXIS).leaves_in_beam == 0


def test_non_finite_position_is_rejected() -> None:
    with pytest.raises(ValueError, match="position"):
        Beam([0.0, math.nan, 0.0], [1, 0, 0], 0.5)
    with pytest.raises(ValueError, match="boresight"):
        Beam([0.0, 0.0, 0.0], [0, 0, 0], 0.5)


def test_float32_inputs_match_float64() -> None:
    c, n, a = cone_cloud(300, seed=3)
    ref = synthesize((c, n, a), ON_AXIS, fidelity="reference").samples
    c32 = (c.astype(np.float32), n.astype(np.float32), a.astype(np.float32))
    got = synthesize(c32, ON_AXIS, fidelity="reference").samples
    ref32 = synthesize(tuple(x.astype(np.float64) for x in c32), ON_AXIS,
                       fidelity="reference").samples
    np.testing.assert_array_equal(got, ref32)
    assert rel_l2(got, ref) < 1e-2  # float32 rounding of the centres moves phases


@settings(max_examples=25, deadline=None)
@given(
    r=st.floats(0.1, 9.9),
    a=st.floats(0.0, 0.5),
    beta=st.sampled_from([0.0, math.pi / 2, 0.3, 1.5707963, 1.2]),
    bw_deg=st.floats(0.1, 179.0),
)
def test_extremes_give_finite_output_equal_in_fast_and_reference(
    r: float, a: float, beta: float, bw_deg: float
) -> None:
    normal = (-math.cos(beta), math.sin(beta), 0.0)
    leaf = one_leaf(r, a, normal)
    beam = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(bw_deg))
    ref = synthesize(leaf, beam, fidelity="reference")
    fast = synthesize(leaf, beam, fidelity="fast")
    assert np.all(np.isfinite(ref.samples)) and np.all(np.isfinite(fast.samples))
    assert ref.leaves_in_beam == fast.leaves_in_beam == 1
    assert rel_l2(fast.samples, ref.samples) < 1e-3 or np.abs(ref.samples).max() == 0.0


def test_leaf_touching_the_sonar_and_a_to_zero() -> None:
    leaf = (np.array([[0.1, 0.0, 0.0], [0.1000001, 0, 0], [0.5, 0, 0]]),
            np.array([[1.0, 0, 0], [1e-300, 0, 0], [1.0, 0, 0]]), np.array([0.0, 1e-9, 1e-12]))
    for fid in ("reference", "fast"):
        echo = synthesize(leaf, ON_AXIS, fidelity=fid)
        assert np.all(np.isfinite(echo.samples)) and echo.samples.any()
    ref = synthesize(leaf, ON_AXIS, fidelity="reference").samples
    assert rel_l2(synthesize(leaf, ON_AXIS, fidelity="fast").samples, ref) < 1e-3


def test_band_edges_at_first_bin_and_nyquist() -> None:
    leaves = cone_cloud(200, seed=7)
    wide = EchoParams(f_lo=FS / 24000, f_hi=FS / 2)  # bin 1 .. Nyquist bin
    ref = synthesize(leaves, ON_AXIS, wide, fidelity="reference")
    fast = synthesize(leaves, ON_AXIS, wide, fidelity="fast")
    assert np.all(np.isfinite(ref.samples)) and np.abs(ref.samples).max() > 0
    assert fast.error_bound is not None
    assert rel_l2(fast.samples, ref.samples) <= max(fast.error_bound, 1e-3)
    narrow = EchoParams(f_lo=70e3, f_hi=70e3 + FS / 24000)  # two bins
    two = synthesize(leaves, ON_AXIS, narrow, fidelity="reference").samples
    assert rel_l2(synthesize(leaves, ON_AXIS, narrow, fidelity="fast").samples, two) < 1e-3
