"""Forest specs (plain data) and the files they name.

A :class:`ForestSpec` lists species (tree model and placement), the domain and the merge rule;
:class:`ForestFiles` holds what the files a spec names contain (grammars, tree maps, CAD
templates), read by the I/O layer and handed to the forest builder. YAML schema:
``docs/world.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple, TypeVar

from sim_core.config import from_dict as _from_dict
from sim_core.world.cad import Mesh
from sim_core.world.ipp import TreeMap
from sim_core.world.lpp import Grammar
from sim_core.world.trees import TREE_MODELS, LppTree

__all__ = [
    "FileNames",
    "ForestFiles",
    "ForestSpec",
    "KDESpec",
    "KernelSpec",
    "SpeciesSpec",
    "TemplateSpec",
    "named_files",
]

T = TypeVar("T")


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
    def from_dict(cls, data: Mapping[str, Any]) -> ForestSpec:
        """Validate a plain mapping (a forest YAML document): unknown keys and bad values raise
        ``ConfigError`` naming the key."""
        return _from_dict(cls, data)


class FileNames(NamedTuple):
    """The files a :class:`ForestSpec` names, as it names them: L++ ``grammars`` (a packaged
    name such as ``"tree4"`` or a path), CSV ``tables`` (tree maps, KDE maps) and CAD
    ``meshes`` (template OBJ/STL files)."""

    grammars: tuple[str, ...]
    tables: tuple[str, ...]
    meshes: tuple[str, ...]


def named_files(spec: ForestSpec) -> FileNames:
    """Every file ``spec`` reads when a forest is built from it, each name once in spec order:
    the grammar of every L++ species (its ``grammar``, else its model's packaged one), the
    ``tree_map`` and ``kde.csv`` tables and the template meshes."""
    grammars: dict[str, None] = {}
    tables: dict[str, None] = {}
    meshes: dict[str, None] = {}
    if spec.tree_map is not None:
        tables[spec.tree_map] = None
    for s in spec.species:
        model = TREE_MODELS[s.tree]
        if s.grammar is not None:
            grammars[s.grammar] = None
        elif isinstance(model, LppTree):
            grammars[model.grammar] = None
        if s.kde is not None:
            tables[s.kde.csv] = None
        if s.template is not None:
            meshes[s.template.leaf] = None
            if s.template.branch is not None:
                meshes[s.template.branch] = None
    return FileNames(tuple(grammars), tuple(tables), tuple(meshes))


@dataclass(frozen=True, eq=False)
class ForestFiles:
    """What the files a :class:`ForestSpec` names hold (:func:`named_files`), keyed by the name
    the spec gives them: parsed L++ ``grammars``, the rows of CSV ``tables`` (tree maps) and
    the arrays of CAD ``meshes``. Reading them is I/O
    (``hil_bridge.files.world.load_forest_files``); a forest of GMT3 trees placed by
    intensities or positions names no file and needs none."""

    grammars: Mapping[str, Grammar] = field(default_factory=dict)
    tables: Mapping[str, TreeMap] = field(default_factory=dict)
    meshes: Mapping[str, Mesh] = field(default_factory=dict)

    def grammar(self, name: str) -> Grammar:
        return _named(self.grammars, name, "L++ grammar")

    def table(self, name: str) -> TreeMap:
        return _named(self.tables, name, "tree map")

    def mesh(self, name: str) -> Mesh:
        return _named(self.meshes, name, "template")


def _named(contents: Mapping[str, T], name: str, what: str) -> T:
    try:
        return contents[name]
    except KeyError:
        raise ValueError(
            f"{what} {name}: not read; read the files the forest names first "
            "(hil_bridge.files.world.load_forest_files)"
        ) from None
