"""IPP by thinning: counts vs ∫λ, clamping, caps, bad intensities; minimum-distance thinning."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import pdist

from hil_bridge.files.world import read_tree_map
from sim_core.world.ipp import (
    Homogeneous,
    KDEIntensity,
    SEMixture,
    TreeMap,
    min_distance_thin,
    sample_ipp,
    tree_map_positions,
)

BOX = (-40.0, -40.0, 60.0, 60.0)


def test_ipp_counts_match_the_integral_over_many_seeds() -> None:
    lam = SEMixture(((0.4, 5.0, 5.0, 5.0, 6.0), (0.3, 15.0, 15.0, 3.0, 6.0)))
    expected = lam.integral()  # both bumps lie well inside BOX
    assert expected == pytest.approx(0.4 * math.pi * math.sqrt(30) + 0.3 * math.pi * math.sqrt(18))
    counts = np.array(
        [sample_ipp(lam, BOX, np.random.default_rng(s)).shape[0] for s in range(400)]
    )
    # Poisson: mean = variance = ∫λ; 5 standard errors
    assert abs(counts.mean() - expected) < 5 * math.sqrt(expected / counts.size)
    assert abs(counts.var() - expected) < 0.35 * expected


def test_ipp_spatial_distribution_follows_lambda() -> None:
    lam = SEMixture(((1.0, 0.0, 0.0, 8.0, 8.0),))
    pts = np.concatenate([sample_ipp(lam, BOX, np.random.default_rng(s)) for s in range(100)])
    # each coordinate ~ N(0, h/2) for exp(-x²/h)
    assert abs(pts[:, 0].mean()) < 0.1 and pts[:, 0].var() == pytest.approx(4.0, rel=0.08)


def test_any_vectorised_callable_and_clamping() -> None:
    def ramp(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return 0.01 * (x - BOX[0]) / 100.0 + 0.0 * y

    counts = [sample_ipp(ramp, BOX, np.random.default_rng(s)).shape[0] for s in range(200)]
    assert np.mean(counts) == pytest.approx(0.005 * 100 * 100, rel=0.05)
    # λ above the bound λ* is clamped to λ*: a bound of half the ramp's max flattens the top half
    clamped = [
        sample_ipp(ramp, BOX, np.random.default_rng(s), lam_max=0.005).shape[0] for s in range(200)
    ]
    assert np.mean(clamped) == pytest.approx(0.75 * 0.005 * 100 * 100, rel=0.05)


def test_huge_intensity_fails_clearly_and_negative_intensity_is_named() -> None:
    with pytest.raises(ValueError, match="huge intensity"):
        sample_ipp(Homogeneous(1e6), BOX, np.random.default_rng(0), max_expected=1e6)
    with pytest.raises(ValueError, match="intensity must be finite and >= 0, got -1"):
        sample_ipp(lambda x, y: -np.ones_like(x), BOX, np.random.default_rng(0), lam_max=1.0)
    with pytest.raises(ValueError, match="peak must be a finite intensity >= 0"):
        SEMixture(((-0.1, 0.0, 0.0, 1.0, 1.0),))
    with pytest.raises(ValueError, match="rate must be"):
        Homogeneous(-1.0)


@settings(max_examples=30, deadline=None)
@given(
    rate=st.floats(0.0, 0.05),
    w=st.floats(0.0, 50.0),
    h=st.floats(0.0, 50.0),
    seed=st.integers(0, 2**31),
)
def test_ipp_points_in_box_and_zero_cases(rate: float, w: float, h: float, seed: int) -> None:
    box = (1.0, 2.0, 1.0 + w, 2.0 + h)
    pts = sample_ipp(Homogeneous(rate), box, np.random.default_rng(seed))
    assert pts.shape[1] == 2
    if rate == 0 or w == 0 or h == 0:
        assert pts.shape[0] == 0
    assert np.all((pts[:, 0] >= 1.0) & (pts[:, 0] <= 1.0 + w))
    assert np.all((pts[:, 1] >= 2.0) & (pts[:, 1] <= 2.0 + h))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 300), d=st.floats(0.0, 20.0), seed=st.integers(0, 2**31))
def test_min_distance_thinning_holds_and_is_greedy(n: int, d: float, seed: int) -> None:
    pts = np.random.default_rng(seed).uniform(0, 100, (n, 2))
    keep = min_distance_thin(pts, d)
    kept = pts[keep]
    if kept.shape[0] > 1 and d > 0:
        assert pdist(kept).min() >= d
    # greedy in order: every dropped point is closer than d to an earlier kept point
    for i in np.flatnonzero(~keep):
        earlier = pts[:i][keep[:i]]
        assert np.min(np.hypot(*(earlier - pts[i]).T)) < d
    if n:
        assert keep[0]


def test_seed001_merge_reproduces_the_stored_forest(data_dir: Path) -> None:
    # Untitled.ipynb: species files in order 1..4, threshold 16, any species blocks any other
    base = data_dir / "seed001"
    pts, labels = [], []
    for k in range(1, 5):
        xy, _ = read_tree_map(base / "ipp_points" / f"points_{k}.csv")
        pts.append(xy)
        labels += [k] * xy.shape[0]
    allpts = np.concatenate(pts)
    keep = min_distance_thin(allpts, 16.0)
    stored, sp = read_tree_map(base / "forest_points.csv")
    np.testing.assert_allclose(allpts[keep], stored)
    assert [int(s or 0) for s in sp] == list(np.asarray(labels)[keep])


def test_kde_intensity_integrates_to_map_size(data_dir: Path) -> None:
    xy, _ = read_tree_map(data_dir / "seed001" / "forest_points.csv")
    lam = KDEIntensity(xy)
    gx, gy = np.meshgrid(np.linspace(-300, 600, 301), np.linspace(-300, 600, 301))
    integral = lam(gx, gy).sum() * (900 / 300) ** 2
    assert integral == pytest.approx(xy.shape[0], rel=0.01)
    bound = lam.upper_bound(None)
    assert bound >= lam(gx, gy).max()
    counts = [
        sample_ipp(lam, (-300, -300, 600, 600), np.random.default_rng(s)).shape[0]
        for s in range(100)
    ]
    assert np.mean(counts) == pytest.approx(31, abs=5 * math.sqrt(31 / 100))


def test_tree_map_positions_scale_and_name_species() -> None:
    rows = TreeMap(np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]), ("2", "b", None), (1, 2, 4),
                   "m.csv")
    xy, species = tree_map_positions(rows, scale=2.0, species_names=["a", "b"])
    np.testing.assert_array_equal(xy, [[2.0, 4.0], [6.0, 8.0], [10.0, 12.0]])
    assert species == ["b", "b", None]
    assert tree_map_positions(rows)[1] == ["2", "b", None]
    with pytest.raises(ValueError, match=r"m\.csv:1: species index 2 out of range 1\.\.1"):
        tree_map_positions(rows, species_names=["a"])
    with pytest.raises(ValueError, match=r"m\.csv:2: unknown species 'b'"):
        tree_map_positions(rows, species_names=["a", "c"])
