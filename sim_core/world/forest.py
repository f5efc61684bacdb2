"""Forests: a spec (plain data), tree placement per species, minimum-distance merge, growth.

Placement (seed 000 §2A.5, seed 001 §2B.6): one process per species — an IPP by thinning with
an intensity (squared-exponential mixture, homogeneous rate, a KDE of a real tree map, or any
Python callable), optionally conditioned on an exact ``count``; or fixed positions (inline or a
tree-map CSV). The species are merged by greedy minimum-distance thinning in a fixed order:
species in spec order, within a species by a uniform random mark (for fixed positions, file
order) — the seed's "first come, first kept" rule with its order made explicit.

Determinism and locality: IPP candidates are drawn per square *cell* of ``cell_size_m`` from the
stream ``derive_rng(seed, "cell", species, ix, iy)`` and every tree grows from its own stream
``derive_rng(seed, "tree", species, ...)``, so a tree never depends on how many others exist, and
any region can be built alone (:class:`sim_core.world.TiledForest`) with exactly the trees a
one-shot build has there.
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from sim_core.config import from_dict as _from_dict
from sim_core.rng import derive_rng
from sim_core.world.cad import CadTree
from sim_core.world.ipp import (
    Box,
    Homogeneous,
    Intensity,
    KDEIntensity,
    SEMixture,
    grid_upper_bound,
    min_distance_thin,
    read_tree_map,
    sample_ipp,
)
from sim_core.world.leaves import Leaves
from sim_core.world.trees import TREE_MODELS, GMT3Tree, LppTree, TreeGeometry, TreeModel

__all__ = [
    "Forest",
    "ForestSpec",
    "KDESpec",
    "KernelSpec",
    "SpeciesSpec",
    "TemplateSpec",
    "build_forest",
    "load_forest_spec",
]

F64 = NDArray[np.float64]


# --- spec ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class KernelSpec:
    """One squared-exponential bump ``peak·exp(−(x−cx)²/div_x − (y−cy)²/div_y)`` (trees/m²)."""

    peak: float
    center: tuple[float, float]
    div: tuple[float, float]

    def __post_init__(self) -> None:
        if not self.peak >= 0:
            raise ValueError(f"peak must be an intensity >= 0 (trees/m²), got {self.peak}")
        if not (self.div[0] > 0 and self.div[1] > 0):
            raise ValueError(f"div must be two divisors > 0 (m²), got {self.div}")


@dataclass(frozen=True)
class KDESpec:
    """Intensity from a real tree map: Gaussian KDE of the CSV's points × ``scale``.

    ``csv`` rows ``x, y[, species]`` in file units (× ``map_scale`` metres); ``species`` keeps only
    rows with that label (name or 1-based index as written); ``bandwidth`` is the KDE factor
    (``None``: Scott's rule).
    """

    csv: str
    bandwidth: float | None = None
    scale: float = 1.0
    map_scale: float = 1.0
    species: str | None = None

    def __post_init__(self) -> None:
        if self.bandwidth is not None and not self.bandwidth > 0:
            raise ValueError(f"bandwidth must be > 0, got {self.bandwidth}")
        if not self.scale >= 0:
            raise ValueError(f"scale must be >= 0, got {self.scale}")
        if not self.map_scale > 0:
            raise ValueError(f"map_scale must be > 0, got {self.map_scale}")


@dataclass(frozen=True)
class TemplateSpec:
    """CAD dressing of a GMT3 species (:mod:`sim_core.world.cad`): OBJ/STL template files.

    ``leaf`` mesh (faces or vertices become leaves), optional ``branch`` mesh (drawn only),
    template frame +x along the branch with ``up_axis`` up, placed on the skeleton branches of
    level ``on_level`` with a random twist ``U(0, twist_max_deg)``.
    """

    leaf: str
    branch: str | None = None
    leaf_from: Literal["faces", "vertices"] = "faces"
    up_axis: Literal["y", "z"] = "y"
    on_level: int = 1
    twist_max_deg: float = 15.0

    def __post_init__(self) -> None:
        if self.on_level < 1:
            raise ValueError(f"on_level must be >= 1, got {self.on_level}")
        if not 0 <= self.twist_max_deg <= 360:
            raise ValueError(f"twist_max_deg must be in [0, 360], got {self.twist_max_deg}")


@dataclass(frozen=True)
class SpeciesSpec:
    """One species: its tree model and how its trees are placed.

    Tree: ``tree`` names a model of :data:`sim_core.world.trees.TREE_MODELS`; ``grammar`` swaps in
    an ``.l++`` file (an L++ model), ``growth_level`` fixes the growth level, ``scale`` multiplies
    the metre scale, ``leaf_size`` picks an L++ model's leaf-size rule (``metres`` or ``seed``,
    see :class:`~sim_core.world.trees.LppTree`), ``template`` dresses a GMT3 skeleton with CAD
    templates.

    Placement (exactly one, unless the forest's ``tree_map`` places this species):
    ``kernels`` (SE mixture), ``rate`` (homogeneous, trees/m²), ``kde`` (from a tree map),
    ``positions`` (fixed ``[x, y]`` list), or ``intensity_fn`` (Python only: vectorised callable
    ``λ(x, y)``; give ``intensity_max`` on an unbounded domain). ``count`` conditions an intensity
    on exactly that many trees (needs a bounded domain).
    """

    name: str
    tree: str = "maple"
    grammar: str | None = None
    growth_level: int | None = None
    scale: float = 1.0
    leaf_size: Literal["metres", "seed"] | None = None
    template: TemplateSpec | None = None
    kernels: tuple[KernelSpec, ...] = ()
    rate: float | None = None
    kde: KDESpec | None = None
    positions: tuple[tuple[float, float], ...] = ()
    count: int | None = None
    intensity_max: float | None = None
    intensity_fn: Any = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("species name must be non-empty")
        if self.tree not in TREE_MODELS:
            raise ValueError(
                f"species {self.name!r}: unknown tree model {self.tree!r}; "
                f"expected one of {sorted(TREE_MODELS)}"
            )
        if self.growth_level is not None and self.growth_level < 0:
            raise ValueError(f"species {self.name!r}: growth_level must be >= 0")
        lpp = self.grammar is not None or isinstance(TREE_MODELS[self.tree], LppTree)
        if self.leaf_size is not None and not lpp:
            raise ValueError(
                f"species {self.name!r}: leaf_size applies to L++ models (tree4..tree7 or a "
                f"grammar), not {self.tree!r}"
            )
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"species {self.name!r}: scale must be > 0, got {self.scale}")
        if self.rate is not None and not (math.isfinite(self.rate) and self.rate >= 0):
            raise ValueError(
                f"species {self.name!r}: rate must be an intensity >= 0 (trees/m²), got {self.rate}"
            )
        if self.count is not None and self.count < 0:
            raise ValueError(f"species {self.name!r}: count must be >= 0, got {self.count}")
        if self.intensity_max is not None and not self.intensity_max >= 0:
            raise ValueError(f"species {self.name!r}: intensity_max must be >= 0")
        if self.intensity_fn is not None and not callable(self.intensity_fn):
            raise ValueError(f"species {self.name!r}: intensity_fn must be callable λ(x, y)")
        if len(self._placements()) > 1:
            raise ValueError(
                f"species {self.name!r}: give one placement, got {self._placements()}"
            )
        if self.count is not None and (self.positions or not self._placements()):
            raise ValueError(f"species {self.name!r}: count needs an intensity to condition")
        if self.template is not None and self.grammar is not None:
            raise ValueError(f"species {self.name!r}: template dresses GMT3 trees, not grammars")

    def _placements(self) -> list[str]:
        given = {
            "kernels": bool(self.kernels),
            "rate": self.rate is not None,
            "kde": self.kde is not None,
            "positions": bool(self.positions),
            "intensity_fn": self.intensity_fn is not None,
        }
        return [k for k, v in given.items() if v]


@dataclass(frozen=True)
class ForestSpec:
    """A forest: species, domain and merge rule (YAML schema in ``docs/world.md``).

    Attributes:
        species: the species, in merge order (earlier species win minimum-distance conflicts).
        domain: ``[xmin, ymin, xmax, ymax]`` metres; ``None`` is the unbounded plane (tiled
            worlds only).
        min_distance_m: minimum distance between tree bases after the merge (0: no thinning).
        tree_map: CSV of fixed trees ``x, y, species`` (name or 1-based index into ``species``).
        tree_map_scale: metres per tree-map unit.
        cell_size_m: side of the square cells in which IPP candidates are drawn.
        max_expected_trees: cap on λ*·area per species; above it building fails ("huge
            intensity") instead of running out of memory.
        max_crown_radius_m: horizontal reach of a crown from its base (tiled worlds look this
            far into neighbouring tiles); ``None``: the models' bounds.
    """

    species: tuple[SpeciesSpec, ...]
    domain: tuple[float, float, float, float] | None = None
    min_distance_m: float = 0.0
    tree_map: str | None = None
    tree_map_scale: float = 1.0
    cell_size_m: float = 50.0
    max_expected_trees: float = 1e5
    max_crown_radius_m: float | None = None

    def __post_init__(self) -> None:
        names = [s.name for s in self.species]
        if len(set(names)) != len(names):
            raise ValueError(f"species names must be unique, got {names}")
        if self.domain is not None:
            x0, y0, x1, y1 = self.domain
            if not (x1 >= x0 and y1 >= y0):
                raise ValueError(f"domain must be [xmin, ymin, xmax, ymax], got {self.domain}")
        if not self.min_distance_m >= 0:
            raise ValueError(f"min_distance_m must be >= 0, got {self.min_distance_m}")
        if not self.cell_size_m > 0:
            raise ValueError(f"cell_size_m must be > 0, got {self.cell_size_m}")
        if not self.tree_map_scale > 0:
            raise ValueError(f"tree_map_scale must be > 0, got {self.tree_map_scale}")
        if not self.max_expected_trees > 0:
            raise ValueError(f"max_expected_trees must be > 0, got {self.max_expected_trees}")
        if self.max_crown_radius_m is not None and not self.max_crown_radius_m >= 0:
            raise ValueError("max_crown_radius_m must be >= 0")
        for s in self.species:
            if self.tree_map is None and not s._placements():
                raise ValueError(
                    f"species {s.name!r}: no placement (kernels, rate, kde, positions, "
                    "intensity_fn) and no tree_map"
                )
            if s.count is not None and self.domain is None:
                raise ValueError(f"species {s.name!r}: count needs a bounded domain")

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, base_dir: str | Path | None = None
    ) -> ForestSpec:
        """Validate a plain mapping (YAML); relative file paths resolve against ``base_dir``."""
        spec = _from_dict(cls, data)
        return spec.resolve_paths(base_dir) if base_dir is not None else spec

    def resolve_paths(self, base_dir: str | Path) -> ForestSpec:
        """Copy with relative ``tree_map``/``kde.csv``/``grammar``/template paths under base."""
        base = Path(base_dir)

        def fix(p: str | None) -> str | None:
            if p is None or Path(p).is_absolute() or not (base / p).exists():
                return p
            return str(base / p)

        species = []
        for s in self.species:
            kde = dataclasses.replace(s.kde, csv=fix(s.kde.csv) or s.kde.csv) if s.kde else None
            tpl = s.template
            if tpl is not None:
                tpl = dataclasses.replace(
                    tpl, leaf=fix(tpl.leaf) or tpl.leaf, branch=fix(tpl.branch)
                )
            species.append(dataclasses.replace(s, kde=kde, grammar=fix(s.grammar), template=tpl))
        return dataclasses.replace(self, species=tuple(species), tree_map=fix(self.tree_map))


def load_forest_spec(path: str | Path) -> ForestSpec:
    """Read a ForestSpec from YAML.

    Accepted: a ForestSpec mapping; the same under a top-level ``forest:`` key; or a server
    scene file whose ``forest:`` section names a ``preset`` or gives ForestSpec fields as
    ``spec`` (:mod:`sim_core.scene`). Relative paths resolve against the file's directory.
    """
    from hil_bridge.files.config import load_yaml
    from sim_core.world.presets import get_preset

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
        return ForestSpec.from_dict(data, base_dir=Path(path).resolve().parent)
    except ValueError as exc:
        raise type(exc)(f"{path}: {exc}") from None


# --- forest ----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Forest:
    """A built forest: all leaves plus one row per tree (``leaves.tree_id`` indexes the rows).

    Attributes:
        leaves: :class:`Leaves` of every tree, tree by tree.
        tree_xy: (T, 2) base positions, metres.
        tree_species: (T,) species names (numpy unicode array).
        tree_height: (T,) tree heights, metres.
        species: species names in spec order (also those with zero trees).
    """

    leaves: Leaves
    tree_xy: F64
    tree_species: NDArray[np.str_]
    tree_height: F64
    species: tuple[str, ...]

    @property
    def n_trees(self) -> int:
        return int(self.tree_xy.shape[0])

    def species_counts(self) -> dict[str, int]:
        """Species name -> number of trees (every species of the spec, zeros included)."""
        return {s: int(np.count_nonzero(self.tree_species == s)) for s in self.species}

    def save_npz(self, path: str | Path) -> None:
        """Write ``centers normals radii tree_id tree_xy tree_species`` (+ ``tree_height``)."""
        self.leaves.save_npz(
            path,
            tree_xy=self.tree_xy,
            tree_species=np.asarray(self.tree_species, dtype=np.str_),
            tree_height=self.tree_height,
        )

    @classmethod
    def load_npz(cls, path: str | Path) -> Forest:
        leaves = Leaves.load_npz(path)
        with np.load(Path(path), allow_pickle=False) as data:
            if "tree_xy" not in data or "tree_species" not in data:
                raise ValueError(f"{path}: not a forest file (no tree_xy/tree_species)")
            xy = np.asarray(data["tree_xy"], dtype=np.float64)
            sp = np.asarray(data["tree_species"], dtype=np.str_)
            h = np.asarray(data["tree_height"]) if "tree_height" in data else np.zeros(len(xy))
        return cls(leaves, xy, sp, h, tuple(dict.fromkeys(sp.tolist())))


# --- the engine shared by build_forest and TiledForest ---------------------------------------


def _zz(i: int) -> int:
    """Zig-zag a signed cell index to a non-negative rng key."""
    return 2 * i if i >= 0 else -2 * i - 1


@dataclass(frozen=True)
class Candidate:
    """A potential tree: species index, priority mark, position and its rng key path."""

    species: int
    mark: float
    x: float
    y: float
    key: tuple[int | str, ...]

    @property
    def priority(self) -> tuple[int, float, tuple[int | str, ...]]:
        return (self.species, self.mark, self.key)


def _model_for(s: SpeciesSpec) -> TreeModel | CadTree:
    model: TreeModel = TREE_MODELS[s.tree]
    if s.grammar is not None:
        base = model if isinstance(model, LppTree) else LppTree(s.grammar)
        model = dataclasses.replace(base, grammar=s.grammar)
    if s.growth_level is not None:
        model = model.with_growth_level(s.growth_level)
    if s.scale != 1.0:
        model = dataclasses.replace(model, unit_m=model.unit_m * s.scale)
    if s.leaf_size is not None and isinstance(model, LppTree):
        model = dataclasses.replace(model, leaf_size=s.leaf_size)
    if s.template is None:
        return model
    if not isinstance(model, GMT3Tree):
        raise ValueError(f"species {s.name!r}: a CAD template needs a GMT3 tree model")
    t = s.template
    cad = CadTree(model, t.leaf, t.branch, leaf_from=t.leaf_from, up_axis=t.up_axis,
                  on_level=t.on_level, twist_max_deg=t.twist_max_deg)
    cad.template()  # an unreadable template fails here, before anything is built
    return cad


#: bound on the horizontal crown reach of the named models (metres, before species ``scale``)
CROWN_BOUND_M: dict[str, float] = {
    "maple": 10.0,
    "maple-single": 5.0,
    "hazelnut-bush": 5.0,
    "tree4": 20.0,
    "tree5": 20.0,
    "tree6": 12.0,
    "tree7": 25.0,
}


class ForestEngine:
    """Candidates, merge and growth for one (spec, seed); used by build_forest and TiledForest."""

    def __init__(self, spec: ForestSpec, *, seed: int, cell_cache: int = 4096) -> None:
        self.spec = spec
        self.seed = seed
        self.names = [s.name for s in spec.species]
        self.models: list[TreeModel | CadTree] = [_model_for(s) for s in spec.species]
        for m in self.models:
            if isinstance(m, LppTree):
                m.load()  # a malformed grammar fails here, before anything is built
        self.intensities: list[Callable[[F64, F64], Any] | None] = []
        self.bounds: list[float] = []
        for s in spec.species:
            fn, bound = self._intensity(s)
            self.intensities.append(fn)
            self.bounds.append(bound)
        self._check_caps()
        self.fixed: list[Candidate] = self._fixed_candidates()
        self._fixed_by_cell: dict[tuple[int, int], list[Candidate]] = {}
        for c in self.fixed:
            self._fixed_by_cell.setdefault(self.cell_of(c.x, c.y), []).append(c)
        self._cells: OrderedDict[tuple[int, int], list[Candidate]] = OrderedDict()
        self._cell_cache = cell_cache

    # intensities ------------------------------------------------------------------------------
    def _intensity(self, s: SpeciesSpec) -> tuple[Callable[[F64, F64], Any] | None, float]:
        dom = self.spec.domain
        fn: Callable[[F64, F64], Any]
        if s.kernels:
            fn = SEMixture(tuple((k.peak, *k.center, *k.div) for k in s.kernels))
        elif s.rate is not None:
            fn = Homogeneous(s.rate)
        elif s.kde is not None:
            xy, labels = read_tree_map(s.kde.csv, scale=s.kde.map_scale)
            if s.kde.species is not None:
                xy = xy[np.asarray([lab == s.kde.species for lab in labels], dtype=bool)]
            fn = KDEIntensity(xy, bandwidth=s.kde.bandwidth, scale=s.kde.scale)
        elif s.intensity_fn is not None:
            fn = s.intensity_fn
        else:
            return None, 0.0
        if s.intensity_max is not None:
            return fn, float(s.intensity_max)
        if isinstance(fn, Intensity):
            return fn, fn.upper_bound(dom)
        if dom is None:
            raise ValueError(
                f"species {s.name!r}: intensity_fn on an unbounded domain needs intensity_max"
            )
        side = max(dom[2] - dom[0], dom[3] - dom[1])
        return fn, grid_upper_bound(fn, dom, spacing=side / 256 or 1.0)

    def _check_caps(self) -> None:
        dom = self.spec.domain
        cap = self.spec.max_expected_trees
        for name, bound in zip(self.names, self.bounds, strict=True):
            if dom is not None:
                area = (dom[2] - dom[0]) * (dom[3] - dom[1])
            else:
                area = self.spec.cell_size_m**2
            where = "the domain" if dom is not None else "one cell"
            if bound * area > cap:
                raise ValueError(
                    f"huge intensity: species {name!r} expects up to {bound * area:.6g} trees on "
                    f"{where} (λ* = {bound:.6g}/m² × {area:.6g} m²) > "
                    f"max_expected_trees = {cap:.6g}"
                )

    # candidates -------------------------------------------------------------------------------
    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        c = self.spec.cell_size_m
        return (math.floor(x / c), math.floor(y / c))

    def _in_domain(self, x: F64, y: F64) -> NDArray[np.bool_]:
        dom = self.spec.domain
        if dom is None:
            return np.ones(np.shape(x), dtype=bool)
        return (x >= dom[0]) & (x <= dom[2]) & (y >= dom[1]) & (y <= dom[3])

    def _fixed_candidates(self) -> list[Candidate]:
        out: list[Candidate] = []
        spec = self.spec
        if spec.tree_map is not None:
            xy, labels = read_tree_map(
                spec.tree_map, scale=spec.tree_map_scale, species_names=self.names
            )
            for j, ((x, y), lab) in enumerate(zip(xy, labels, strict=True)):
                if lab is None:
                    raise ValueError(f"{spec.tree_map}: row {j + 1} has no species column")
                k = self.names.index(lab)
                out.append(Candidate(k, (j + 0.5) / len(labels), x, y, ("map", j)))
        for k, s in enumerate(spec.species):
            if s.positions:
                n = len(s.positions)
                for j, (x, y) in enumerate(s.positions):
                    out.append(Candidate(k, (j + 0.5) / n, float(x), float(y), (s.name, "pos", j)))
            if s.count is not None:
                out.extend(self._conditioned(k, s))
        xs = np.asarray([c.x for c in out])
        ys = np.asarray([c.y for c in out])
        inside = self._in_domain(xs, ys) if out else np.zeros(0, bool)
        return [c for c, ok in zip(out, inside, strict=True) if ok]

    def _conditioned(self, k: int, s: SpeciesSpec) -> list[Candidate]:
        """``count`` points i.i.d. with density ∝ λ on the domain (the IPP given N = count)."""
        dom = self.spec.domain
        fn, bound = self.intensities[k], self.bounds[k]
        if dom is None or fn is None or s.count is None:
            raise ValueError(f"species {s.name!r}: count needs an intensity and a domain")
        if s.count > self.spec.max_expected_trees:
            raise ValueError(f"species {s.name!r}: count {s.count} > max_expected_trees")
        if bound == 0 and s.count > 0:
            raise ValueError(
                f"species {s.name!r}: intensity is zero on the domain; cannot place {s.count} trees"
            )
        rng = derive_rng(self.seed, "count", s.name)
        pts: list[F64] = []
        have, drawn = 0, 0
        while have < s.count:
            batch = max(64, 4 * (s.count - have))
            x = rng.uniform(dom[0], dom[2], batch)
            y = rng.uniform(dom[1], dom[3], batch)
            lam = np.asarray(fn(x, y), dtype=np.float64)
            if np.any(~np.isfinite(lam) | (lam < 0)):
                raise ValueError(f"species {s.name!r}: intensity must be finite and >= 0")
            ok = rng.random(batch) * bound < np.minimum(lam, bound)
            pts.append(np.column_stack([x[ok], y[ok]]))
            have += int(ok.sum())
            drawn += batch
            if have < s.count and drawn > 10_000_000:
                raise ValueError(
                    f"species {s.name!r}: intensity is (almost) zero on the domain; cannot place "
                    f"{s.count} trees"
                )
        xy = np.concatenate(pts)[: s.count]
        marks = rng.random(s.count)
        return [
            Candidate(k, float(marks[j]), float(xy[j, 0]), float(xy[j, 1]), (s.name, "count", j))
            for j in range(s.count)
        ]

    def cell_candidates(self, cell: tuple[int, int]) -> list[Candidate]:
        """All candidates (IPP and fixed) whose base lies in ``cell``, deterministic per cell."""
        hit = self._cells.get(cell)
        if hit is not None:
            self._cells.move_to_end(cell)
            return hit
        ix, iy = cell
        c = self.spec.cell_size_m
        box: Box = (ix * c, iy * c, (ix + 1) * c, (iy + 1) * c)
        dom = self.spec.domain
        out: list[Candidate] = list(self._fixed_by_cell.get(cell, ()))
        if dom is not None:
            box = (
                max(box[0], dom[0]), max(box[1], dom[1]), min(box[2], dom[2]), min(box[3], dom[3])
            )
        if box[2] > box[0] and box[3] > box[1]:
            for k, s in enumerate(self.spec.species):
                fn = self.intensities[k]
                if fn is None or s.count is not None or self.bounds[k] == 0:
                    continue
                rng = derive_rng(self.seed, "cell", s.name, _zz(ix), _zz(iy))
                bound = fn.upper_bound(box) if isinstance(fn, Intensity) else self.bounds[k]
                pts = sample_ipp(
                    fn, box, rng, lam_max=min(bound, self.bounds[k]),
                    max_expected=self.spec.max_expected_trees,
                )
                # a point on a cell's upper edge belongs to the next cell
                pts = pts[(pts[:, 0] < ix * c + c) & (pts[:, 1] < iy * c + c)] if pts.size else pts
                marks = np.asarray(rng.random((pts.shape[0],)))
                out.extend(
                    Candidate(k, float(marks[j]), float(pts[j, 0]), float(pts[j, 1]),
                              (s.name, "ipp", _zz(ix), _zz(iy), j))
                    for j in range(pts.shape[0])
                )
        out.sort(key=lambda cand: cand.priority)
        self._cells[cell] = out
        while len(self._cells) > self._cell_cache:
            self._cells.popitem(last=False)
        return out

    def cells_in(self, box: Box) -> list[tuple[int, int]]:
        c = self.spec.cell_size_m
        x0, y0 = math.floor(box[0] / c), math.floor(box[1] / c)
        x1, y1 = math.floor(box[2] / c), math.floor(box[3] / c)
        return [(i, j) for i in range(x0, x1 + 1) for j in range(y0, y1 + 1)]

    # merge ------------------------------------------------------------------------------------
    def kept_in(self, box: Box) -> list[Candidate]:
        """Trees (kept candidates) with base in ``[x0, x1) × [y0, y1)``, in priority order.

        Exact greedy minimum-distance result computed locally: a candidate's fate depends only
        on higher-priority candidates closer than ``min_distance_m`` (recursively), so the
        closure of blockers is gathered and thinned greedily.
        """
        targets = [
            cand
            for cell in self.cells_in(box)
            for cand in self.cell_candidates(cell)
            if box[0] <= cand.x < box[2] and box[1] <= cand.y < box[3]
        ]
        d = self.spec.min_distance_m
        if d <= 0 or not targets:
            return sorted(targets, key=lambda cand: cand.priority)
        closure: dict[tuple[int | str, ...], Candidate] = {c.key: c for c in targets}
        frontier = list(targets)
        while frontier:
            xs = [c.x for c in frontier]
            ys = [c.y for c in frontier]
            pool_box = (min(xs) - d, min(ys) - d, max(xs) + d, max(ys) + d)
            pool = [p for cell in self.cells_in(pool_box) for p in self.cell_candidates(cell)]
            tree = cKDTree(np.asarray([[p.x, p.y] for p in pool]))
            hits = tree.query_ball_point(np.column_stack([xs, ys]), d)
            new: list[Candidate] = []
            for c, near in zip(frontier, hits, strict=True):
                for j in near:
                    p = pool[j]
                    if (
                        p.key not in closure
                        and p.priority < c.priority
                        and math.hypot(p.x - c.x, p.y - c.y) < d
                    ):
                        closure[p.key] = p
                        new.append(p)
            frontier = new
        ordered = sorted(closure.values(), key=lambda cand: cand.priority)
        keep = min_distance_thin(np.asarray([[c.x, c.y] for c in ordered]), d)
        target_keys = {c.key for c in targets}
        return [c for c, k in zip(ordered, keep, strict=True) if k and c.key in target_keys]

    def all_kept(self) -> list[Candidate]:
        """All trees of a bounded forest, in priority order (greedy over every candidate)."""
        dom = self.spec.domain
        if dom is None:
            if any(f is not None for f in self.intensities):
                raise ValueError("an unbounded forest (domain: null) can only be built by tiles")
            cands = sorted(self.fixed, key=lambda cand: cand.priority)
        else:
            cands = sorted(
                (c for cell in self.cells_in(dom) for c in self.cell_candidates(cell)),
                key=lambda cand: cand.priority,
            )
        if self.spec.min_distance_m > 0 and cands:
            xy = np.asarray([[c.x, c.y] for c in cands])
            keep = min_distance_thin(xy, self.spec.min_distance_m)
            cands = [c for c, k in zip(cands, keep, strict=True) if k]
        return cands

    # growth -----------------------------------------------------------------------------------
    def grow(self, cand: Candidate, *, branches: bool = False) -> TreeGeometry:
        """The tree of ``cand`` in world coordinates (its own rng stream)."""
        rng = derive_rng(self.seed, "tree", *cand.key)
        geo = self.models[cand.species].grow(rng, branches=branches)
        shift = np.array([cand.x, cand.y, 0.0])
        return dataclasses.replace(
            geo,
            centers=geo.centers + shift,
            seg_start=geo.seg_start + shift,
            seg_end=geo.seg_end + shift,
        )

    def crown_bound(self) -> float:
        """Horizontal reach (m) used by tiled queries to look into neighbouring tiles."""
        if self.spec.max_crown_radius_m is not None:
            return self.spec.max_crown_radius_m
        out = 0.0
        for s in self.spec.species:
            base = CROWN_BOUND_M[s.tree] if s.grammar is None else 40.0 * _model_for(s).unit_m
            if s.template is not None:
                base *= 2.0  # a template may be wider than the branch it is scaled to
            out = max(out, base * s.scale)
        return out

    def assemble(self, cands: Iterable[Candidate]) -> Forest:
        """Grow ``cands`` and pack them into a :class:`Forest` (tree ids in the given order)."""
        cands = list(cands)
        geos = [self.grow(c) for c in cands]
        parts = [
            Leaves(g.centers, g.normals, g.radii, np.full(g.radii.shape[0], i, dtype=np.int32))
            for i, g in enumerate(geos)
        ]
        return Forest(
            leaves=Leaves.concat(parts),
            tree_xy=np.asarray([[c.x, c.y] for c in cands], dtype=np.float64).reshape(-1, 2),
            tree_species=np.asarray([self.names[c.species] for c in cands], dtype=np.str_),
            tree_height=np.asarray([g.height for g in geos], dtype=np.float64),
            species=tuple(self.names),
        )


def build_forest(spec: ForestSpec, *, seed: int) -> Forest:
    """Build every tree of a bounded forest (or of fixed positions only) with all leaves."""
    engine = ForestEngine(spec, seed=seed)
    return engine.assemble(engine.all_kept())
