"""The blocked geometry pass (model.prepare) against the spec's formulas written out directly."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_core.sonar import Beam, EchoParams
from sim_core.sonar.geometry import GEOMETRY_BLOCK
from sim_core.sonar.model import _exp, prepare
from tests.sim_core.sonar._scenes import cone_cloud


def _spec_selection(
    c: np.ndarray, n: np.ndarray, a: np.ndarray, beam: Beam, params: EchoParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Kept indices, beta and S of docs/spec/echo_model.md, one array expression each."""
    d = c - beam.position
    r = np.sqrt((d * d).sum(1))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = d / r[:, None]
        theta = np.arccos(np.clip(u @ beam.boresight, -1.0, 1.0))
        s1 = params.peak_amplitude * np.exp(-(theta**2) / (2.0 * beam.sigma**2))
        nn = np.sqrt((n * n).sum(1))
        valid = np.isfinite(c).all(1) & np.isfinite(n).all(1) & np.isfinite(a) & (nn > 0)
        valid &= r >= params.r_min
        keep = valid & (r <= params.selection_radius * s1)
        beta = np.arccos(np.clip(np.abs((n * u).sum(1)) / nn, 0.0, 1.0))
    idx = np.flatnonzero(keep)
    return idx, beta[idx], (s1 * s1)[idx], int(c.shape[0] - np.count_nonzero(valid))


def test_blocked_selection_matches_the_spec_over_several_blocks() -> None:
    m = 2 * GEOMETRY_BLOCK + 123
    c, n, a = cone_cloud(m, seed=21, half_angle_deg=70.0, r_lo=0.0, r_hi=14.0)
    c[5] = np.nan
    n[7] = 0.0
    a[9] = np.inf
    beam = Beam([0.2, -0.1, 0.3], [1.0, 0.2, -0.1], math.radians(40.0))
    params = EchoParams()
    idx, beta, gain, dropped = _spec_selection(c, n, a, beam, params)
    scene = prepare((c, n, a), beam, params)
    assert scene.count == scene.in_beam == idx.shape[0] > 1000
    assert scene.dropped == dropped >= 3
    np.testing.assert_allclose(scene.beta[0], beta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(scene.beam[0], gain / ((c[idx] - beam.position) ** 2).sum(1),
                               rtol=1e-12)


def test_leaves_on_the_waterdrop_boundary_are_decided_by_the_spec_formula() -> None:
    beam = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(30.0))
    theta = np.linspace(0.0, 0.5, 401)
    r = 10.0 * np.exp(-(theta**2) / (2.0 * beam.sigma**2))
    r = np.concatenate([r * (1.0 - 1e-15), r * (1.0 + 1e-15), r])
    theta = np.tile(theta, 3)
    c = np.stack([r * np.cos(theta), r * np.sin(theta), np.zeros_like(r)], 1)
    n = np.tile([1.0, 0.0, 0.0], (r.shape[0], 1))
    a = np.full(r.shape[0], 0.02)
    idx, _, _, _ = _spec_selection(c, n, a, beam, EchoParams())
    scene = prepare((c, n, a), beam, EchoParams())
    assert scene.count == idx.shape[0]
    np.testing.assert_allclose(np.sort(scene.tau[0]), np.sort(2.0 * np.sqrt((c[idx] ** 2).sum(1))
                                                              / 340.0), rtol=1e-14)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-30.0, 0.0), min_size=1, max_size=50))
def test_refined_float32_exponential_is_float64_accurate(xs: list[float]) -> None:
    x = np.array(xs)
    np.testing.assert_allclose(_exp(x), np.exp(x), rtol=1e-14, atol=0)


def test_exponential_falls_back_below_its_refinement_range() -> None:
    x = np.array([-1.0, -200.0, -800.0])
    np.testing.assert_array_equal(_exp(x), np.exp(x))
