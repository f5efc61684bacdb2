"""CAD templates from files (hil_bridge.files.world) dressing GMT3 trees (sim_core.world.cad):
templates built with trimesh primitives, written as OBJ and STL."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from hil_bridge.files.world import load_forest_files, load_template
from sim_core.world import ForestSpec, SpeciesSpec, TemplateSpec, build_forest
from sim_core.world.cad import CadTree
from sim_core.world.trees import GMT3Tree


def _leaf_cluster(tmp_path: Path, ext: str) -> Path:
    """Four flat square 'leaves' (2 triangles each) along +x, z up, facing +z."""
    parts = []
    for i in range(4):
        leaf = trimesh.creation.box(extents=(0.1, 0.1, 1e-3))
        leaf.apply_translation((0.25 * (i + 1), 0.0, 0.05 * i))
        parts.append(leaf)
    mesh = trimesh.util.concatenate(parts)
    path = tmp_path / f"leaves.{ext}"
    mesh.export(path)
    return path


@pytest.mark.parametrize("ext", ["obj", "stl"])
def test_template_faces_become_leaves(tmp_path: Path, ext: str) -> None:
    path = _leaf_cluster(tmp_path, ext)
    tpl = load_template(str(path), leaf_from="faces", up_axis="z")
    assert tpl.points.shape[0] == 4 * 12
    assert tpl.length == pytest.approx(1.05)
    model = CadTree(GMT3Tree(levels=3), tpl)
    geo = model.grow(np.random.default_rng(0), branches=True)
    skel, _ = GMT3Tree(levels=3).skeleton(np.random.default_rng(0))
    n_branches = int(((skel.level == 1) & ~skel.main_axis).sum())
    assert geo.centers.shape[0] == n_branches * tpl.points.shape[0]
    np.testing.assert_allclose(np.linalg.norm(geo.normals, axis=1), 1.0, atol=1e-9)
    assert np.all(geo.radii >= 1e-3)
    # the big faces (0.1 x 0.1 m before scaling) keep their area as an equivalent disc
    assert geo.radii.max() > geo.radii.min()


def test_template_rotates_to_branch_azimuth(tmp_path: Path) -> None:
    path = _leaf_cluster(tmp_path, "obj")
    tpl = load_template(str(path), up_axis="z")
    model = CadTree(GMT3Tree(levels=1, scale_sd=0.0), tpl, twist_max_deg=0.0)
    geo = model.grow(np.random.default_rng(4))
    skel, scale = GMT3Tree(levels=1, scale_sd=0.0).skeleton(np.random.default_rng(4))
    side = skel.vec[(skel.level == 1) & ~skel.main_axis] * scale
    k = geo.centers.shape[0] // side.shape[0]
    for b, v in enumerate(side):
        c = geo.centers[b * k : (b + 1) * k]
        start = skel.start[(skel.level == 1) & ~skel.main_axis][b] * scale
        horiz = c[:, :2] - start[:2]
        az = np.arctan2(horiz[:, 1], horiz[:, 0])
        assert np.allclose(np.angle(np.exp(1j * (az - np.arctan2(v[1], v[0])))), 0.0, atol=0.25)


def test_vertex_leaves_and_forest_with_template(tmp_path: Path) -> None:
    path = _leaf_cluster(tmp_path, "stl")
    spec = ForestSpec(
        species=(
            SpeciesSpec(
                "m", tree="maple", growth_level=2, positions=((0.0, 0.0), (10.0, 0.0)),
                template=TemplateSpec(leaf=str(path), leaf_from="vertices", up_axis="z"),
            ),
        )
    )
    f = build_forest(spec, seed=0, files=load_forest_files(spec))
    assert f.n_trees == 2 and len(f.leaves) > 0
    assert np.all((f.leaves.radii > 0.01) & (f.leaves.radii < 0.04))


def test_unreadable_template_fails_clearly(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no such file"):
        load_template(str(tmp_path / "none.obj"))
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match=r"junk.obj: no faces found"):
        load_template(str(junk))
    spec = ForestSpec(
        species=(SpeciesSpec("m", positions=((0.0, 0.0),),
                             template=TemplateSpec(leaf=str(junk))),)
    )
    with pytest.raises(ValueError, match="no faces found"):
        build_forest(spec, seed=0, files=load_forest_files(spec))
