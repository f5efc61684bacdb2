"""Tree models: GMT3 structure, leaf normals and radii, metre scale, determinism per stream
(L++ models grow from their packaged grammars, read by hil_bridge.files.world)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hil_bridge.files.world import load_tree_model
from sim_core.world.gmt3 import grow_skeleton
from sim_core.world.spec import SpeciesSpec
from sim_core.world.trees import (
    LEAF_DISC_RATIO,
    TREE_MODELS,
    GMT3Tree,
    LppTree,
    get_tree_model,
)

SEED_LEAF_SIZE = {"tree4": 1.5, "tree5": 1.6, "tree6": 1.1, "tree7": 1.4}  # R3Mesh.cpp


def test_gmt3_forest_variant_counts() -> None:
    skel = grow_skeleton(np.random.default_rng(0), levels=6)
    assert int((~skel.terminal).sum()) == 364 and int(skel.terminal.sum()) == 729
    # every child starts at its parent's end; side children shrink by 0.62, the leader by 0.826
    lengths = np.linalg.norm(skel.vec, axis=1)
    assert np.isclose(lengths[1] / lengths[0], 0.62, rtol=0.3)
    np.testing.assert_allclose(skel.radius[skel.level == 2], 0.04 * 0.7**2)


def test_gmt3_whorl_geometry() -> None:
    skel = grow_skeleton(np.random.default_rng(1), levels=1, twist_max_deg=0.0)
    trunk, left, centre, right = skel.vec
    assert np.allclose(trunk[:2], 0) and np.allclose(centre[:2], 0)
    for side in (left, right):
        ang = np.degrees(np.arccos(side @ trunk / np.linalg.norm(side) / np.linalg.norm(trunk)))
        assert ang == pytest.approx(50.0)
    assert np.linalg.norm(centre) == pytest.approx(0.826 * np.linalg.norm(trunk))


def test_gmt3_non_vertical_children_rotate_towards_horizontal_perpendicular() -> None:
    skel = grow_skeleton(np.random.default_rng(2), levels=2)
    parent = skel.vec[1]  # a side branch of the trunk (level 1, not vertical)
    kids = skel.vec[np.all(np.isclose(skel.start, skel.start[1] + parent), axis=1)]
    assert kids.shape[0] == 3
    phat = np.array([-parent[1], parent[0], 0.0]) / np.hypot(parent[0], parent[1])
    normal = np.cross(parent, phat)
    angles = []
    for v in kids:
        cos = v @ parent / np.linalg.norm(v) / np.linalg.norm(parent)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
        assert abs(v @ normal) < 1e-9 * np.linalg.norm(v)  # in the plane of parent and p-hat
    np.testing.assert_allclose(sorted(angles), [0.0, 50.0, 50.0], atol=1e-6)


def test_single_variant_is_doubled() -> None:
    skel = grow_skeleton(np.random.default_rng(0), variant="single")
    assert skel.start.shape[0] == 11  # d(d)+d)[d(d)+d) plus its rotated copy without trunk


@pytest.mark.parametrize("name", sorted(TREE_MODELS))
def test_leaves_unit_normals_and_radii_bounds(name: str) -> None:
    model = load_tree_model(name)
    geo = model.grow(np.random.default_rng(7))
    assert geo.centers.shape[0] > 0
    assert np.all(np.isfinite(geo.centers)) and np.all(np.isfinite(geo.normals))
    np.testing.assert_allclose(np.linalg.norm(geo.normals, axis=1), 1.0, atol=1e-12)
    mean, sd = model.leaf_radius_mean_m, model.leaf_radius_sd_m
    assert geo.radii.min() >= max(1e-3, mean - 2 * sd) - 1e-15
    assert geo.radii.max() <= mean + 2 * sd + 1e-15
    assert abs(geo.radii.mean() - mean) < 0.1 * mean


@pytest.mark.parametrize("name", ["tree4", "tree5", "tree6", "tree7", "maple"])
def test_trees_are_5_to_25_m_tall(name: str) -> None:
    model = load_tree_model(name)
    if isinstance(model, LppTree) and name == "tree6":
        model = dataclasses.replace(model, growth_jitter=False)  # keep the test fast
    heights = [model.grow(np.random.default_rng(s)).height for s in range(6)]
    assert 5.0 <= min(heights) and max(heights) <= 25.0


def test_lpp_leaf_keep_probability_and_frame_reset() -> None:
    tree4 = load_tree_model("tree4")
    assert isinstance(tree4, LppTree)
    model = dataclasses.replace(tree4, growth_jitter=False, iterations=4)
    a = model.grow(np.random.default_rng(3))
    # growing another tree first must not change this tree (no leaked turtle state)
    model.grow(np.random.default_rng(99))
    b = model.grow(np.random.default_rng(3))
    np.testing.assert_array_equal(a.centers, b.centers)
    every = dataclasses.replace(model, keep_prob=1.0).grow(np.random.default_rng(3))
    ratios = []
    for s in range(10):
        half = model.grow(np.random.default_rng(s)).centers.shape[0]
        full = dataclasses.replace(model, keep_prob=1.0).grow(np.random.default_rng(s))
        ratios.append(half / full.centers.shape[0])
    assert every.centers.shape[0] > 100 and abs(np.mean(ratios) - 0.5) < 0.05


def test_growth_level_zero_is_the_axiom() -> None:
    tree4 = load_tree_model("tree4")
    assert isinstance(tree4, LppTree)
    lpp = dataclasses.replace(tree4, iterations=0, growth_jitter=False)
    geo = lpp.grow(np.random.default_rng(0), branches=True)
    assert geo.centers.shape[0] == 0 and geo.seg_start.shape[0] == 9  # fffffffffA
    assert geo.height == pytest.approx(9 * lpp.unit_m)
    gmt = GMT3Tree(levels=0)
    bare = gmt.grow(np.random.default_rng(0), branches=True)
    assert bare.seg_start.shape[0] == 1 and bare.centers.shape[0] > 0


@pytest.mark.parametrize("name", sorted(SEED_LEAF_SIZE))
def test_lpp_seed_leaf_size_is_the_seeds_clipped_normal_in_grammar_units(name: str) -> None:
    """leaf_size 'seed': length N(leafSize, 15 %) clipped at ±2σ in grammar units, radius
    0.3206 × length × unit_m; the default stays N(μ, 20 %) truncated, in metres."""
    model = load_tree_model(name)
    assert isinstance(model, LppTree) and model.seed_leaf_size == SEED_LEAF_SIZE[name]
    seed = dataclasses.replace(model, leaf_size="seed", growth_jitter=False,
                               iterations=model.rules().iterations - 1)
    length = np.concatenate([seed.grow(np.random.default_rng(s)).radii for s in range(4)])
    length /= LEAF_DISC_RATIO * model.unit_m
    size = SEED_LEAF_SIZE[name]
    assert length.size > 400
    assert length.min() == pytest.approx(0.7 * size) and length.max() == pytest.approx(1.3 * size)
    clipped = np.mean(np.isclose(length, 0.7 * size) | np.isclose(length, 1.3 * size))
    assert 0.02 < clipped < 0.08  # 4.6 % of a normal lies beyond ±2σ
    assert abs(length.mean() / size - 1.0) < 0.02
    assert abs(length.std() / size - 0.15 * 0.96) < 0.02  # sd of the clipped deviate: 0.96 σ


def test_lpp_branches_have_the_seed_radius_and_leave_the_leaves_alone() -> None:
    tree4 = load_tree_model("tree4")
    assert isinstance(tree4, LppTree)
    model = dataclasses.replace(tree4, growth_jitter=False, iterations=3)
    bare = model.grow(np.random.default_rng(4))
    full = model.grow(np.random.default_rng(4), branches=True)
    for name in ("centers", "normals", "radii"):
        np.testing.assert_array_equal(getattr(bare, name), getattr(full, name))
    # the trunk "fffffffff" before any '>': 60 % of a 0.4 m segment
    np.testing.assert_allclose(full.seg_radius[:9], 0.6 * model.unit_m, rtol=1e-12)
    assert full.seg_radius.min() > 0 and full.seg_radius.max() == full.seg_radius[0]
    assert np.unique(np.round(full.seg_radius, 12)).size > 3  # narrowed by '>(30)' per level


def test_species_leaf_size_applies_to_lpp_models_only() -> None:
    assert SpeciesSpec("a", tree="tree5", leaf_size="seed", rate=0.01).leaf_size == "seed"
    assert SpeciesSpec("g", tree="maple", grammar="tree4", leaf_size="seed", rate=0.01)
    with pytest.raises(ValueError, match="leaf_size applies to L\\+\\+ models"):
        SpeciesSpec("b", tree="maple", leaf_size="seed", rate=0.01)
    with pytest.raises(ValueError, match="leaf_size must be 'metres' or 'seed'"):
        LppTree("tree4", leaf_size="huge")  # type: ignore[arg-type]


def test_unknown_model_and_bad_params() -> None:
    with pytest.raises(ValueError, match="unknown tree model 'oak'"):
        get_tree_model("oak")
    with pytest.raises(ValueError, match="leaf_radius_mean_m"):
        GMT3Tree(leaf_radius_mean_m=0.0)
    with pytest.raises(ValueError, match="keep_prob"):
        LppTree("tree4", keep_prob=2.0)
    with pytest.raises(ValueError, match="L\\+\\+ grammar tree4: not read"):
        get_tree_model("tree4").grow(np.random.default_rng(0))


@pytest.mark.parametrize("name", sorted(TREE_MODELS))
def test_crowns_stay_within_the_tiling_bound(name: str) -> None:
    from sim_core.world.forest import CROWN_BOUND_M

    model = load_tree_model(name)
    if isinstance(model, LppTree):  # the largest growth level the ±1 draw can give
        model = dataclasses.replace(model, iterations=model.rules().iterations + 1,
                                    growth_jitter=False)
    reach = max(model.grow(np.random.default_rng(s)).crown_radius for s in range(2))
    assert reach < 0.8 * CROWN_BOUND_M[name]
