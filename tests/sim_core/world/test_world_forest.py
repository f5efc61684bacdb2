"""Forests: determinism, independence of trees, merge rule, presets, specs, tiles vs one-shot
(forest files: tests/hil_bridge/files/test_world.py)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import pdist

from hil_bridge.files.world import load_forest_files as files_of
from sim_core.config import ConfigError
from sim_core.world import (
    Forest,
    ForestFiles,
    ForestSpec,
    KernelSpec,
    Leaves,
    SpeciesSpec,
    TiledForest,
    build_forest,
    get_preset,
    named_files,
    preset_names,
)
from sim_core.world.ball import block_bounds

# a small, quick mixed forest: a bush IPP and an L++ species at low growth level, 6 m merge
SMALL = ForestSpec(
    domain=(0.0, 0.0, 60.0, 60.0),
    min_distance_m=6.0,
    cell_size_m=20.0,
    species=(
        SpeciesSpec("bush", tree="hazelnut-bush", growth_level=2, rate=0.01),
        SpeciesSpec("t4", tree="tree4", growth_level=3,
                    kernels=(KernelSpec(peak=0.02, center=(30.0, 30.0), div=(400.0, 400.0)),)),
    ),
)


def _build(spec: ForestSpec, *, seed: int) -> Forest:
    """``spec`` built with the files it names (packaged grammars, tree maps) read."""
    return build_forest(spec, seed=seed, files=files_of(spec))


def _same(a: Forest, b: Forest) -> bool:
    return (
        a.leaves == b.leaves
        and np.array_equal(a.tree_xy, b.tree_xy)
        and np.array_equal(a.tree_species, b.tree_species)
    )


def test_same_seed_identical_different_seed_different() -> None:
    a, b, c = (_build(SMALL, seed=s) for s in (4, 4, 5))
    assert a.n_trees > 5 and _same(a, b) and not _same(a, c)


@pytest.mark.parametrize("name", ["single-maple", "seed000-fig5d"])
def test_presets_are_deterministic(name: str) -> None:
    spec = get_preset(name)
    assert _same(_build(spec, seed=2), _build(spec, seed=2))
    assert not _same(_build(spec, seed=2), _build(spec, seed=3))


def test_adding_a_tree_does_not_change_the_others() -> None:
    pos = ((0.0, 0.0), (20.0, 0.0))
    one = ForestSpec(species=(SpeciesSpec("m", tree="hazelnut-bush", positions=pos),))
    more = (*pos, (40.0, 0.0))
    two = ForestSpec(species=(SpeciesSpec("m", tree="hazelnut-bush", positions=more),))
    a, b = _build(one, seed=1), _build(two, seed=1)
    assert b.n_trees == 3
    assert a.leaves == b.leaves.select(b.leaves.tree_id < 2)
    # an extra species does not change the trees of the first
    extra = dataclasses.replace(
        SMALL, species=(*SMALL.species, SpeciesSpec("z", tree="tree5", positions=((-500.0, 0),)))
    )
    assert _same(_build(SMALL, seed=3), _build(extra, seed=3))  # (-500, 0) is outside


def test_min_distance_holds_across_species() -> None:
    f = _build(SMALL, seed=8)
    assert set(f.tree_species) == {"bush", "t4"}
    assert pdist(f.tree_xy).min() >= 6.0


def test_seed000_fig5d_counts_and_leaves() -> None:
    f = _build(get_preset("seed000-fig5d"), seed=0)
    assert f.species_counts() == {"maple": 4, "hazelnut": 1}
    assert np.all((f.tree_xy >= 0) & (f.tree_xy <= 20))
    assert np.array_equal(np.unique(f.leaves.tree_id), np.arange(5))
    np.testing.assert_allclose(np.linalg.norm(f.leaves.normals, axis=1), 1.0, atol=1e-12)


def test_seed001_fig9_map_is_the_stored_forest(data_dir: Path) -> None:
    spec = get_preset("seed001-fig9")
    spec = dataclasses.replace(
        spec, species=tuple(dataclasses.replace(s, growth_level=2) for s in spec.species)
    )
    f = _build(spec, seed=0)
    stored = np.loadtxt(data_dir / "seed001" / "forest_points.csv", delimiter=",")
    np.testing.assert_allclose(f.tree_xy, stored[:, :2])
    assert f.species_counts() == {"tree4": 10, "tree5": 6, "tree6": 8, "tree7": 7}


def test_every_preset_builds_a_spec() -> None:
    for name in preset_names():
        assert isinstance(get_preset(name), ForestSpec)
    with pytest.raises(ValueError, match="unknown preset 'x'; expected one of"):
        get_preset("x")


def test_spec_from_dict_names_the_key() -> None:
    with pytest.raises(ConfigError, match=r"species\[0\].kernels\[0\]: peak must be"):
        ForestSpec.from_dict(
            {"species": [{"name": "a", "kernels": [{"peak": -1, "center": [0, 0], "div": [1, 1]}]}]}
        )
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['colour'\]"):
        ForestSpec.from_dict({"species": [{"name": "a", "rate": 0.1, "colour": "red"}]})
    with pytest.raises(ConfigError, match="no placement"):
        ForestSpec.from_dict({"species": [{"name": "a"}]})
    with pytest.raises(ConfigError, match="unknown tree model 'oak'"):
        ForestSpec.from_dict({"species": [{"name": "a", "tree": "oak", "rate": 0.1}]})


def test_named_files_and_a_file_not_read_fail_clearly() -> None:
    spec = dataclasses.replace(SMALL, tree_map="map.csv")
    assert named_files(spec) == (("tree4",), ("map.csv",), ())
    with pytest.raises(ValueError, match=r"L\+\+ grammar tree4: not read"):
        build_forest(SMALL, seed=0)
    with pytest.raises(ValueError, match=r"tree map map\.csv: not read"):
        build_forest(spec, seed=0, files=ForestFiles(grammars=files_of(SMALL).grammars))


def test_huge_intensity_cap_fails_before_building() -> None:
    spec = ForestSpec(domain=(0, 0, 1000, 1000), species=(SpeciesSpec("a", rate=1.0),))
    with pytest.raises(ValueError, match="huge intensity: species 'a' expects up to 1e\\+06"):
        _build(spec, seed=0)


def test_kde_species_mimics_a_site(data_dir: Path) -> None:
    csv = str(data_dir / "seed001" / "forest_points.csv")
    spec = ForestSpec.from_dict(
        {
            "domain": [-100, -100, 400, 400],
            "species": [
                {"name": "s", "tree": "hazelnut-bush", "growth_level": 0,
                 "kde": {"csv": csv, "species": "4"}},
            ],
        }
    )
    counts = [len(_build(spec, seed=s).tree_xy) for s in range(12)]
    assert 3 < np.mean(counts) < 11  # 7 trees of species 4 in the map


def test_callable_intensity_and_conditioned_count() -> None:
    spec = ForestSpec(
        domain=(0, 0, 10, 10),
        species=(
            SpeciesSpec("a", tree="hazelnut-bush", growth_level=0, count=7,
                        intensity_fn=lambda x, y: np.where(x < 5, 1.0, 0.0)),
        ),
    )
    f = _build(spec, seed=0)
    assert f.n_trees == 7 and np.all(f.tree_xy[:, 0] < 5)


@settings(max_examples=16, deadline=None)
@given(
    rate=st.sampled_from([0.0, 1e-9, 0.002, 50.0]),
    side=st.sampled_from([0.0, 1.0, 30.0]),
    level=st.integers(0, 2),
    seed=st.integers(0, 1000),
)
def test_extreme_parameters(rate: float, side: float, level: int, seed: int) -> None:
    spec = ForestSpec(
        domain=(0.0, 0.0, side, side),
        max_expected_trees=1000.0,
        species=(SpeciesSpec("a", tree="tree7", growth_level=level, rate=rate),),
    )
    if rate * side * side > 1000.0:
        with pytest.raises(ValueError, match="huge intensity: species 'a'"):
            _build(spec, seed=seed)
        return
    f = _build(spec, seed=seed)
    if rate == 0 or side == 0:
        assert f.n_trees == 0 and len(f.leaves) == 0
    assert f.species_counts() == {"a": f.n_trees}
    assert np.all(np.isfinite(f.leaves.centers)) and np.all(np.isfinite(f.leaves.normals))
    one = ForestSpec(species=(SpeciesSpec("a", tree="tree7", growth_level=level,
                                          positions=((1.0, 2.0),)),))
    g = _build(one, seed=seed)
    assert g.n_trees == 1 and np.all(g.leaves.tree_id == 0)


def _sorted_rows(leaves: Leaves) -> np.ndarray:
    rows = np.column_stack([leaves.centers, leaves.normals, leaves.radii])
    return rows[np.lexsort(rows.T[::-1])]


@pytest.mark.parametrize("tile", [13.0, 25.0])
def test_tiles_equal_a_one_shot_build(tile: float) -> None:
    one_shot = _build(SMALL, seed=6)
    world = TiledForest(SMALL, seed=6, files=files_of(SMALL),
                        tile_size_m=tile, max_cache_bytes=1 << 30)
    n = int(np.ceil(60.0 / tile))
    tiled = world.trees_in_tiles([(i, j) for i in range(n + 1) for j in range(n + 1)])
    assert tiled.n_trees == one_shot.n_trees
    np.testing.assert_array_equal(np.sort(tiled.tree_height), np.sort(one_shot.tree_height))
    np.testing.assert_array_equal(_sorted_rows(tiled.leaves), _sorted_rows(one_shot.leaves))
    for p in ([10.0, 50.0, 3.0], [30.0, 30.0, 5.0], [59.0, 1.0, 0.0]):
        near = world.leaves_near(np.array(p), 12.0)
        ref = one_shot.leaves.select(one_shot.leaves.query_ball(np.array(p), 12.0))
        np.testing.assert_array_equal(_sorted_rows(near), _sorted_rows(ref))


def test_tiled_cache_is_bounded_and_unbounded_worlds_work() -> None:
    spec = ForestSpec(species=(SpeciesSpec("b", tree="hazelnut-bush", growth_level=2, rate=0.01),))
    world = TiledForest(spec, seed=1, files=files_of(spec),
                        tile_size_m=20.0, max_cache_bytes=400_000)
    for x in np.linspace(-500, 500, 15):
        leaves = world.leaves_near(np.array([x, 3 * x, 2.0]), 10.0)
        assert world.cache_bytes <= 400_000
        if len(leaves):
            assert np.all(np.linalg.norm(leaves.centers - [x, 3 * x, 2.0], axis=1) <= 10.0)
    assert world.evictions > 0
    # tiles are deterministic per (seed, tile): a fresh world rebuilds the same tile
    again = TiledForest(spec, seed=1, files=files_of(spec), tile_size_m=20.0)
    assert world.tile((3, -4)) == again.tile((3, -4))
    with pytest.raises(ValueError, match="only be built by tiles"):
        _build(spec, seed=1)


def _charged(world: TiledForest) -> int:
    """What the cache should charge when every cached tile was gathered from or ensured: leaf
    arrays, their blocks' boxes, 1 KiB a tile."""
    return sum(world.tile(t).nbytes + block_bounds(world.tile(t).centers).nbytes + 1024
               for t in world.cached_tiles)


def test_a_bounded_forest_visits_only_its_own_tiles_and_a_source_stands_in_for_build() -> None:
    built: list[tuple[int, int]] = []
    world = TiledForest(SMALL, seed=6, files=files_of(SMALL),
                        tile_size_m=20.0, max_cache_bytes=1 << 30)

    def source(tile: tuple[int, int]) -> Any:
        built.append(tile)
        return world.build(tile)

    world.source = source
    # a 5 km query around the domain (60 x 60 m, tiles 0..3 with the upper edge) touches 16 tiles
    near = world.leaves_near(np.array([30.0, 30.0, 2.0]), 5000.0)
    assert sorted(built) == [(i, j) for i in range(4) for j in range(4)]
    assert len(near) == len(_build(SMALL, seed=6).leaves)
    assert world.cache_bytes == _charged(world)
    world.forget((1, 1))
    assert (1, 1) not in world.cached_tiles
    assert world.cache_bytes == _charged(world)
    world.tile((1, 1))  # fetched again, not boxed: only gathers and ensure() box a tile
    assert world.cache_bytes == _charged(world) - block_bounds(world.tile((1, 1)).centers).nbytes
    tile = world.ensure((1, 1))  # boxed ahead of the gathers
    assert built.count((1, 1)) == 2 and (1, 1) in world.cached_tiles
    assert world.cache_bytes == _charged(world)
    assert tile.leaves.nbytes == 60 * len(tile.leaves)


def test_tiled_reach_check_fails_clearly() -> None:
    spec = dataclasses.replace(SMALL, max_crown_radius_m=0.5)
    world = TiledForest(spec, seed=6, files=files_of(spec), tile_size_m=30.0)
    with pytest.raises(ValueError, match=r"raise forest\.max_crown_radius_m"):
        world.leaves_near(np.array([30.0, 30.0, 5.0]), 30.0)


def test_tiny_cache_stays_consistent() -> None:
    world = TiledForest(SMALL, seed=6, files=files_of(SMALL), tile_size_m=20.0, max_cache_bytes=1)
    for p in ([10.0, 10.0, 2.0], [50.0, 50.0, 2.0], [10.0, 10.0, 2.0]):
        ref = _build(SMALL, seed=6).leaves
        near = world.leaves_near(np.array(p), 15.0)
        expect = ref.select(ref.query_ball(np.array(p), 15.0))
        np.testing.assert_array_equal(_sorted_rows(near), _sorted_rows(expect))
        assert world.cache_bytes <= 1 and world.cached_tiles == []


def test_count_on_zero_intensity_fails_clearly() -> None:
    spec = ForestSpec(
        domain=(0, 0, 10, 10),
        species=(SpeciesSpec("a", count=2,
                             kernels=(KernelSpec(peak=1.0, center=(500, 500), div=(1, 1)),)),),
    )
    with pytest.raises(ValueError, match="intensity is zero on the domain"):
        _build(spec, seed=0)
