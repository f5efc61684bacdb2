"""Forests built from a spec: tree placement per species, minimum-distance merge, growth.

Placement (seed 000 §2A.5, seed 001 §2B.6): one process per species — an IPP by thinning with
an intensity (squared-exponential mixture, homogeneous rate, a KDE of a real tree map, or any
Python callable), optionally conditioned on an exact ``count``; or fixed positions (inline or a
tree map). The species are merged by greedy minimum-distance thinning in a fixed order:
species in spec order, within a species by a uniform random mark (for fixed positions, file
order) — the seed's "first come, first kept" rule with its order made explicit.

Determinism and locality: IPP candidates are drawn per square *cell* of ``cell_size_m`` from the
stream ``derive_rng(seed, "cell", species, ix, iy)`` and every tree grows from its own stream
``derive_rng(seed, "tree", species, ...)``, so a tree never depends on how many others exist, and
any region can be built alone (:class:`sim_core.world.TiledForest`) with exactly the trees a
one-shot build has there.

The spec is :mod:`sim_core.world.spec`; the grammars, tree maps and CAD templates it names come
in read, as a :class:`~sim_core.world.spec.ForestFiles`.
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from sim_core.rng import derive_rng
from sim_core.world.cad import CadTree, make_template
from sim_core.world.ipp import (
    Box,
    Homogeneous,
    Intensity,
    KDEIntensity,
    SEMixture,
    grid_upper_bound,
    min_distance_thin,
    sample_ipp,
    tree_map_positions,
)
from sim_core.world.leaves import Leaves
from sim_core.world.spec import ForestFiles, ForestSpec, SpeciesSpec
from sim_core.world.trees import TREE_MODELS, GMT3Tree, LppTree, TreeGeometry, TreeModel

__all__ = ["CROWN_BOUND_M", "Forest", "ForestEngine", "build_forest"]

F64 = NDArray[np.float64]


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


def _model_for(s: SpeciesSpec, files: ForestFiles) -> TreeModel | CadTree:
    model: TreeModel = TREE_MODELS[s.tree]
    if s.grammar is not None:
        base = model if isinstance(model, LppTree) else LppTree(s.grammar)
        model = dataclasses.replace(base, grammar=s.grammar)
    if isinstance(model, LppTree):  # a malformed grammar failed when it was parsed
        model = model.with_grammar(files.grammar(model.grammar))
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
    branch = None if t.branch is None else files.mesh(t.branch)
    template = make_template(files.mesh(t.leaf), branch, leaf_from=t.leaf_from,
                             up_axis=t.up_axis, source=t.leaf)
    return CadTree(model, template, on_level=t.on_level, twist_max_deg=t.twist_max_deg)


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
    """Candidates, merge and growth for one (spec, seed); used by build_forest and TiledForest.

    ``files``: what the files the spec names hold (:class:`~sim_core.world.spec.ForestFiles`;
    a name missing from it fails here, before anything is built).
    """

    def __init__(
        self, spec: ForestSpec, *, seed: int, files: ForestFiles | None = None,
        cell_cache: int = 4096,
    ) -> None:
        self.spec = spec
        self.seed = seed
        self.files = ForestFiles() if files is None else files
        self.names = [s.name for s in spec.species]
        self.models: list[TreeModel | CadTree] = [
            _model_for(s, self.files) for s in spec.species
        ]
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
            xy, labels = tree_map_positions(self.files.table(s.kde.csv), scale=s.kde.map_scale)
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
            xy, labels = tree_map_positions(
                self.files.table(spec.tree_map), scale=spec.tree_map_scale,
                species_names=self.names,
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
        for s, model in zip(self.spec.species, self.models, strict=True):
            base = CROWN_BOUND_M[s.tree] if s.grammar is None else 40.0 * model.unit_m
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


def build_forest(spec: ForestSpec, *, seed: int, files: ForestFiles | None = None) -> Forest:
    """Build every tree of a bounded forest (or of fixed positions only) with all leaves;
    ``files``: what the files ``spec`` names hold (none needed when it names none)."""
    engine = ForestEngine(spec, seed=seed, files=files)
    return engine.assemble(engine.all_kept())
