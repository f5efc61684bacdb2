"""hil_bridge.files.world: forest specs and the files they name, grammars, tree maps, leaves and
forests as .npz, the packaged data behind the presets."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.files.world import (
    load_forest,
    load_forest_files,
    load_forest_spec,
    load_grammar,
    load_leaves,
    load_tree_model,
    packaged_grammar,
    read_tree_map,
    save_forest,
    save_leaves,
    table_path,
)
from sim_core.world import (
    Forest,
    ForestSpec,
    KernelSpec,
    Leaves,
    SpeciesSpec,
    build_forest,
    get_preset,
    named_files,
)
from sim_core.world.lpp import GrammarError
from sim_core.world.presets import SEED001_TREE_MAP
from sim_core.world.trees import LppTree

SPECIES = ["tree4", "tree5", "tree6", "tree7"]

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


def _same(a: Forest, b: Forest) -> bool:
    return (
        a.leaves == b.leaves
        and np.array_equal(a.tree_xy, b.tree_xy)
        and np.array_equal(a.tree_species, b.tree_species)
    )


@pytest.mark.parametrize("name", SPECIES)
def test_packaged_grammars_match_the_seed_files(name: str, data_dir: Path) -> None:
    packaged = packaged_grammar(name)
    original = data_dir / "seed001" / "lplusplus" / f"{name}.l++"
    assert packaged.read_bytes() == original.read_bytes()
    g = load_grammar(packaged)
    header = {
        "tree4": (7, 15, 60), "tree5": (7, 15, 90), "tree6": (6, 37, 75), "tree7": (6, 37, 75)
    }
    assert (g.iterations, g.default_angle_deg, g.thickness_pct) == header[name]
    model = load_tree_model(name)
    assert isinstance(model, LppTree) and model.rules() == g


def test_unreadable_grammar_file(tmp_path: Path) -> None:
    with pytest.raises(GrammarError, match="cannot read"):
        load_grammar(tmp_path / "missing.l++")
    bad = tmp_path / "bad.l++"
    bad.write_text("7\n15\n60\nfA\nA=[f\n@\n")
    with pytest.raises(GrammarError, match=re.escape(f"{bad}:5 (rule 'A')")):
        load_grammar(bad)
    spec = ForestSpec(species=(SpeciesSpec("a", tree="tree4", grammar=str(bad),
                                           positions=((0.0, 0.0),)),))
    with pytest.raises(GrammarError, match=re.escape(f"{bad}:5 (rule 'A')")):
        load_forest_files(spec)


def test_tree_map_errors(tmp_path: Path) -> None:
    bad = tmp_path / "m.csv"
    bad.write_text("x,y,species\n1,2,oak\n")
    with pytest.raises(ValueError, match="unknown species 'oak'"):
        read_tree_map(bad, species_names=["maple"])
    bad.write_text("1,2,1\n3,abc,1\n")
    with pytest.raises(ValueError, match=r"m.csv:2: expected 'x, y\[, species\]'"):
        read_tree_map(bad)
    bad.write_text("1,2,3\n")
    with pytest.raises(ValueError, match="species index 3 out of range"):
        read_tree_map(bad, species_names=["a", "b"])
    with pytest.raises(ValueError, match="cannot read tree map"):
        read_tree_map(tmp_path / "missing.csv")


def test_packaged_tree_map_is_the_seed_map(data_dir: Path) -> None:
    packaged, _ = read_tree_map(table_path(SEED001_TREE_MAP))
    stored, _ = read_tree_map(data_dir / "seed001" / "forest_points.csv")
    np.testing.assert_array_equal(packaged, stored)
    assert table_path("a/b.csv") == Path("a/b.csv")


def test_forest_files_hold_what_the_spec_names() -> None:
    spec = get_preset("seed001-fig9")
    files = load_forest_files(spec)
    names = named_files(spec)
    assert sorted(files.grammars) == sorted(names.grammars) == SPECIES
    assert list(files.tables) == [SEED001_TREE_MAP] and not files.meshes
    assert not load_forest_files(get_preset("seed000-fig5d")).grammars


def test_leaves_npz_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    leaves = Leaves(rng.uniform(-10, 10, (50, 3)), normals, rng.uniform(0.01, 0.04, 50),
                    rng.integers(0, 5, 50))
    path = tmp_path / "l.npz"
    save_leaves(leaves, path)
    assert load_leaves(path) == leaves
    np.savez(tmp_path / "bad.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="missing"):
        load_leaves(tmp_path / "bad.npz")


def test_forest_npz_round_trip(tmp_path: Path) -> None:
    f = build_forest(SMALL, seed=1, files=load_forest_files(SMALL))
    save_forest(f, tmp_path / "f.npz")
    with np.load(tmp_path / "f.npz") as data:
        assert {"centers", "normals", "radii", "tree_id", "tree_xy", "tree_species"} <= set(data)
    g = load_forest(tmp_path / "f.npz")
    assert _same(f, g)
    save_leaves(f.leaves, tmp_path / "leaves.npz")
    with pytest.raises(ValueError, match="not a forest file"):
        load_forest(tmp_path / "leaves.npz")


def test_spec_yaml_resolves_paths_against_its_directory(tmp_path: Path) -> None:
    (tmp_path / "map.csv").write_text("5,5,oak\n30,30,birch\n")
    (tmp_path / "scene.yaml").write_text(
        "forest:\n"
        "  domain: [0, 0, 40, 40]\n"
        "  tree_map: map.csv\n"
        "  species:\n"
        "    - {name: oak, tree: hazelnut-bush, growth_level: 2}\n"
        "    - {name: birch, tree: tree4, growth_level: 2}\n"
    )
    spec = load_forest_spec(tmp_path / "scene.yaml")
    assert spec.tree_map == str(tmp_path / "map.csv")
    f = build_forest(spec, seed=0, files=load_forest_files(spec))
    assert f.tree_species.tolist() == ["oak", "birch"]
    (tmp_path / "scene.yaml").write_text("species: [{name: a, colour: red, rate: 0.1}]\n")
    with pytest.raises(ValueError, match=r"scene\.yaml: .*unknown key\(s\) \['colour'\]"):
        load_forest_spec(tmp_path / "scene.yaml")


def test_server_scene_file_forest_section(tmp_path: Path) -> None:
    scene = tmp_path / "scene.yaml"
    scene.write_text("forest: {preset: seed000-fig5d, tiled: true}\nsonars: []\n")
    assert load_forest_spec(scene) == get_preset("seed000-fig5d")
    scene.write_text(
        "forest:\n  tiled: false\n  spec:\n    species: [{name: a, positions: [[1, 2]]}]\n"
    )
    assert load_forest_spec(scene).species[0].positions == ((1.0, 2.0),)
