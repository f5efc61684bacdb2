"""World files: forest specs and the files they name (L++ grammars, tree-map CSVs, CAD meshes),
leaves and forests as ``.npz``, and the packaged grammars and tree map behind the presets.

Names in a spec: a grammar named without the ``.l++`` suffix or a directory (``"tree4"``) is a
packaged grammar (``data/world/lplusplus/NAME.l++``); a table named without a suffix or a
directory (``"seed001_forest_points"``) is a packaged tree map (``data/world/NAME.csv``); any
other name is a file path. :func:`load_forest_files` reads everything a spec names
(:func:`sim_core.world.named_files`) into the :class:`sim_core.world.ForestFiles` the forest
builders take. Every reader names the file in its error.

Leaves ``.npz``: ``centers (M,3)``, ``normals (M,3)``, ``radii (M,)``, ``tree_id (M,)``; a
forest adds ``tree_xy (T,2)``, ``tree_species (T,)`` and ``tree_height (T,)``.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from hil_bridge.files.config import load_npz, load_yaml
from sim_core.world.cad import Mesh, Template, make_template
from sim_core.world.forest import Forest
from sim_core.world.ipp import TreeMap, tree_map_positions
from sim_core.world.leaves import Leaves
from sim_core.world.lpp import Grammar, GrammarError, parse_grammar
from sim_core.world.presets import get_preset
from sim_core.world.spec import ForestFiles, ForestSpec, named_files
from sim_core.world.trees import LppTree, TreeModel, get_tree_model

__all__ = [
    "grammar_path",
    "load_forest",
    "load_forest_files",
    "load_forest_spec",
    "load_grammar",
    "load_leaves",
    "load_mesh",
    "load_template",
    "load_tree_map",
    "load_tree_model",
    "packaged_grammar",
    "read_tree_map",
    "resolve_paths",
    "save_forest",
    "save_leaves",
    "table_path",
]


def _data() -> Path:
    return Path(str(resources.files("hil_bridge.files") / "data" / "world"))


def _is_bare(name: str) -> bool:
    p = Path(name)
    return p.suffix == "" and p.parent == Path(".")


# --- forest specs ------------------------------------------------------------------------------


def resolve_paths(spec: ForestSpec, base_dir: str | Path) -> ForestSpec:
    """Copy of ``spec`` with relative ``tree_map``/``kde.csv``/``grammar``/template paths that
    exist under ``base_dir`` made paths under it (others are left as written)."""
    base = Path(base_dir)

    def fix(p: str | None) -> str | None:
        if p is None or Path(p).is_absolute() or not (base / p).exists():
            return p
        return str(base / p)

    species = []
    for s in spec.species:
        kde = dataclasses.replace(s.kde, csv=fix(s.kde.csv) or s.kde.csv) if s.kde else None
        tpl = s.template
        if tpl is not None:
            tpl = dataclasses.replace(tpl, leaf=fix(tpl.leaf) or tpl.leaf, branch=fix(tpl.branch))
        species.append(dataclasses.replace(s, kde=kde, grammar=fix(s.grammar), template=tpl))
    return dataclasses.replace(spec, species=tuple(species), tree_map=fix(spec.tree_map))


def load_forest_spec(path: str | Path) -> ForestSpec:
    """Read a ForestSpec from YAML.

    Accepted: a ForestSpec mapping; the same under a top-level ``forest:`` key; or a server
    scene file whose ``forest:`` section names a ``preset`` or gives ForestSpec fields as
    ``spec`` (:mod:`sim_core.scene`). Relative paths resolve against the file's directory.
    """
    data = load_yaml(path)
    if isinstance(data, Mapping) and "forest" in data and "species" not in data:
        data = data["forest"]
        if isinstance(data, Mapping) and "species" not in data:
            if data.get("preset") is not None:
                return get_preset(str(data["preset"]))
            if data.get("spec") is not None:
                data = data["spec"]
    if not isinstance(data, Mapping):
        raise ValueError(f"{path}: expected a mapping with a 'species' list")
    try:
        return resolve_paths(ForestSpec.from_dict(data), Path(path).resolve().parent)
    except ValueError as exc:
        raise type(exc)(f"{path}: {exc}") from None


# --- the files a spec names ----------------------------------------------------------------------


def packaged_grammar(name: str) -> Path:
    """Path of a grammar shipped in ``hil_bridge/files/data/world/lplusplus`` (``"tree4"``)."""
    return _data() / "lplusplus" / f"{name}.l++"


def grammar_path(name: str) -> Path:
    """The file of grammar ``name``: a packaged grammar for a bare name (``"tree4"``), else the
    path itself."""
    p = Path(name)
    if p.suffix == ".l++" or p.parent != Path("."):
        return p
    return packaged_grammar(name)


def load_grammar(path: str | Path) -> Grammar:
    """Read and parse an ``.l++`` file (an unreadable file raises ``GrammarError``)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise GrammarError(f"{p}: cannot read L++ grammar ({reason})") from None
    return parse_grammar(text, source=str(p))


@functools.lru_cache(maxsize=64)
def _grammar(path: str) -> Grammar:
    return load_grammar(path)


def load_tree_model(name: str) -> TreeModel:
    """The named tree model (:func:`sim_core.world.trees.get_tree_model`), an L++ model with its
    packaged grammar read."""
    model = get_tree_model(name)
    if isinstance(model, LppTree):
        return model.with_grammar(_grammar(str(grammar_path(model.grammar))))
    return model


def table_path(name: str) -> Path:
    """The file of tree map ``name``: a packaged tree map for a bare name
    (``"seed001_forest_points"``), else the path itself."""
    return _data() / f"{name}.csv" if _is_bare(name) else Path(name)


def load_tree_map(path: str | Path) -> TreeMap:
    """Read a tree map CSV: rows ``x, y[, species]`` (no header, or a header row of names;
    ``#`` lines and blank lines skipped); ``ValueError`` naming ``file:line``."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ValueError(f"{p}: cannot read tree map ({reason})") from None
    xy: list[tuple[float, float]] = []
    labels: list[str | None] = []
    lines: list[int] = []
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        try:
            x, y = float(cells[0]), float(cells[1])
        except (ValueError, IndexError):
            if lineno == 1:
                continue  # header row
            raise ValueError(
                f"{p}:{lineno}: expected 'x, y[, species]' numbers, got {row}"
            ) from None
        if not (np.isfinite(x) and np.isfinite(y)):
            raise ValueError(f"{p}:{lineno}: coordinates must be finite, got {row}")
        xy.append((x, y))
        labels.append(cells[2] if len(cells) > 2 and cells[2] else None)
        lines.append(lineno)
    return TreeMap(np.asarray(xy, dtype=np.float64).reshape(-1, 2), tuple(labels), tuple(lines),
                   str(p))


def read_tree_map(
    path: str | Path, *, scale: float = 1.0, species_names: Sequence[str] = ()
) -> tuple[NDArray[np.float64], list[str | None]]:
    """Positions and species of a tree map CSV (:func:`load_tree_map`,
    :func:`sim_core.world.ipp.tree_map_positions`): coordinates times ``scale`` (metres per
    file unit), a species a name or a 1-based index into ``species_names``."""
    return tree_map_positions(load_tree_map(path), scale=scale, species_names=species_names)


@functools.lru_cache(maxsize=32)
def load_mesh(path: str) -> Mesh:
    """The arrays of an OBJ/STL mesh (trimesh); ``ValueError`` naming the file when it cannot
    be read, is not a mesh or has no faces."""
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"template {path}: cannot read (no such file)")
    mesh: Any
    try:
        mesh = trimesh.load(str(p), force="mesh")
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise ValueError(f"template {path}: cannot load as OBJ/STL mesh ({exc})") from None
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise ValueError(f"template {path}: no faces found (not a readable OBJ/STL mesh)")
    return Mesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        vertex_normals=np.asarray(mesh.vertex_normals, dtype=np.float64),
        face_centers=np.asarray(mesh.triangles_center, dtype=np.float64),
        face_normals=np.asarray(mesh.face_normals, dtype=np.float64),
        face_areas=np.asarray(mesh.area_faces, dtype=np.float64),
        edges=np.asarray(mesh.edges_unique, dtype=np.int64),
    )


def load_template(
    leaf: str,
    branch: str | None = None,
    *,
    leaf_from: Literal["faces", "vertices"] = "faces",
    up_axis: Literal["y", "z"] = "y",
) -> Template:
    """The CAD template of leaf (and branch) mesh files (:func:`sim_core.world.cad.make_template`);
    unreadable files raise ``ValueError`` naming the path."""
    return make_template(load_mesh(leaf), None if branch is None else load_mesh(branch),
                         leaf_from=leaf_from, up_axis=up_axis, source=leaf)


def load_forest_files(spec: ForestSpec) -> ForestFiles:
    """Read every file ``spec`` names (:func:`sim_core.world.named_files`): its grammars, tree
    maps and template meshes, keyed by the names the spec gives them."""
    names = named_files(spec)
    return ForestFiles(
        grammars={n: _grammar(str(grammar_path(n))) for n in names.grammars},
        tables={n: load_tree_map(table_path(n)) for n in names.tables},
        meshes={n: load_mesh(n) for n in names.meshes},
    )


# --- leaves and forests as .npz ------------------------------------------------------------------


def save_leaves(leaves: Leaves, path: str | Path, **extra: Any) -> None:
    """Write ``centers``, ``normals``, ``radii``, ``tree_id`` (and ``extra`` arrays) to npz."""
    np.savez(
        Path(path),
        centers=leaves.centers,
        normals=leaves.normals,
        radii=leaves.radii,
        tree_id=leaves.tree_id,
        **extra,
    )


def _leaves(path: Path, data: Mapping[str, Any]) -> Leaves:
    missing = [k for k in ("centers", "normals", "radii", "tree_id") if k not in data]
    if missing:
        raise ValueError(f"{path}: not a leaves file, missing arrays {missing}")
    try:
        return Leaves(data["centers"], data["normals"], data["radii"], data["tree_id"])
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def load_leaves(path: str | Path) -> Leaves:
    """Read the four leaf arrays written by :func:`save_leaves` (extra arrays are ignored)."""
    p = Path(path)
    return _leaves(p, load_npz(p))


def save_forest(forest: Forest, path: str | Path) -> None:
    """Write ``centers normals radii tree_id tree_xy tree_species`` (+ ``tree_height``)."""
    save_leaves(
        forest.leaves,
        path,
        tree_xy=forest.tree_xy,
        tree_species=np.asarray(forest.tree_species, dtype=np.str_),
        tree_height=forest.tree_height,
    )


def load_forest(path: str | Path) -> Forest:
    """Read a forest written by :func:`save_forest`."""
    p = Path(path)
    data = load_npz(p)
    leaves = _leaves(p, data)
    if "tree_xy" not in data or "tree_species" not in data:
        raise ValueError(f"{path}: not a forest file (no tree_xy/tree_species)")
    xy = np.asarray(data["tree_xy"], dtype=np.float64)
    sp = np.asarray(data["tree_species"], dtype=np.str_)
    h = np.asarray(data["tree_height"]) if "tree_height" in data else np.zeros(len(xy))
    return Forest(leaves, xy, sp, h, tuple(dict.fromkeys(sp.tolist())))
