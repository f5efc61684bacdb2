"""Tree models in metres: seed 000 GMT3 skeletons and seed 001 L++ grammars, plus named presets.

A tree model is a frozen dataclass with ``grow(rng, *, branches=False) -> TreeGeometry``; all
randomness of one tree comes from the one ``rng`` it is given (the forest derives a separate
stream per tree). Geometry is in metres, z up, the tree's base at the origin.

Acoustic leaf radius (both families): N(mean, sd²) truncated to [max(1 mm, mean − 2 sd),
mean + 2 sd]; the default N(2.5 cm, 0.5 cm). This draw is the leaf-size noise of the seeds.

L++ trees (seed 001): the grammar's segment length 1 is ``unit_m`` metres (the seed fixes no
unit); the leaf polygon's length follows from the acoustic radius through the template's
equivalent-disc ratio (radius = 0.3206 × length), so leaf centres sit at the centroid of a
realistically sized 8-gon. Leaf normal = the minimal rotation +Y → heading applied to +Z
(the seed's ``drawLeaf``); the L++ frame (y up) maps to ENU as (x, y, z) -> (x, −z, y).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sim_core.world.geometry import clipped_normal, rotate, truncated_normal
from sim_core.world.gmt3 import Skeleton, grow_skeleton, skeleton_leaves
from sim_core.world.lpp import (
    Grammar,
    branch_radii,
    expand,
    growth_level,
    interpret,
)

__all__ = [
    "LEAF_DISC_RATIO",
    "TREE_MODELS",
    "GMT3Tree",
    "LppTree",
    "TreeGeometry",
    "TreeModel",
    "get_tree_model",
]

F64 = NDArray[np.float64]

#: equivalent-disc radius of the seed 001 leaf polygon per unit leaf length (spec §2B.5)
LEAF_DISC_RATIO = 0.3206


@dataclass(frozen=True, eq=False)
class TreeGeometry:
    """One tree in metres (z up, base at the origin).

    Attributes:
        centers, normals: (M, 3) leaf centres and unit normals.
        radii: (M,) acoustic leaf radii, metres.
        seg_start, seg_end: (S, 3) branch segments (empty unless grown with ``branches=True``).
        seg_radius: (S,) branch radii, metres.
    """

    centers: F64
    normals: F64
    radii: F64
    seg_start: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    seg_end: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    seg_radius: F64 = field(default_factory=lambda: np.zeros(0))

    @property
    def height(self) -> float:
        """Highest leaf or branch point, metres."""
        zs = [a[:, 2].max() for a in (self.centers, self.seg_end) if a.shape[0]]
        return float(max(zs)) if zs else 0.0

    @property
    def crown_radius(self) -> float:
        """Largest horizontal distance of a leaf (or branch end) from the base, metres."""
        rs = [np.hypot(a[:, 0], a[:, 1]).max() for a in (self.centers, self.seg_end) if a.shape[0]]
        return float(max(rs)) if rs else 0.0


def _leaf_radii(rng: np.random.Generator, mean: float, sd: float, n: int) -> F64:
    low = max(1e-3, mean - 2.0 * sd)
    return truncated_normal(rng, mean, sd, low, max(low, mean + 2.0 * sd), n)


def _check_leaf_radius(mean: float, sd: float) -> None:
    if not (mean >= 1e-3):
        raise ValueError(f"leaf_radius_mean_m must be >= 0.001 m, got {mean}")
    if not (sd >= 0):
        raise ValueError(f"leaf_radius_sd_m must be >= 0, got {sd}")


@dataclass(frozen=True)
class GMT3Tree:
    """Seed 000 GMT3 skeleton with leaves along branches and at tips (see :mod:`.gmt3`).

    ``unit_m`` metres per model unit; each tree is further scaled by a clipped normal
    N(1, ``scale_sd``) (the seed's random scale).
    """

    variant: Literal["forest", "single"] = "forest"
    levels: int = 6
    trunk: float = 2.0
    angle_deg: float = 50.0
    ratio_side: float = 0.62
    ratio_centre: float = 0.826
    divergence_deg: float = -43.75
    radius0: float = 0.04
    radius_ratio: float = 0.7
    sprout: tuple[float, float] = (0.2, 0.7)
    twist_max_deg: float = 15.0
    nodes: int = 4
    leaves_per_node: int = 4
    tip_leaves: int = 4
    node_jitter: float = 0.1
    tip_jitter: float = 0.05
    unit_m: float = 1.0
    scale_sd: float = 0.1
    leaf_radius_mean_m: float = 0.025
    leaf_radius_sd_m: float = 0.005

    def __post_init__(self) -> None:
        if self.levels < 0:
            raise ValueError(f"levels must be >= 0, got {self.levels}")
        if not (self.unit_m > 0 and self.trunk > 0):
            raise ValueError(f"unit_m and trunk must be > 0, got {self.unit_m}, {self.trunk}")
        if not (0 <= self.sprout[0] <= self.sprout[1]):
            raise ValueError(f"sprout must be (low, high) with 0 <= low <= high, got {self.sprout}")
        if self.nodes < 0 or self.leaves_per_node < 0 or self.tip_leaves < 0:
            raise ValueError("nodes, leaves_per_node and tip_leaves must be >= 0")
        if not (0 <= self.scale_sd < 0.5):
            raise ValueError(f"scale_sd must be in [0, 0.5), got {self.scale_sd}")
        _check_leaf_radius(self.leaf_radius_mean_m, self.leaf_radius_sd_m)

    def with_growth_level(self, level: int) -> GMT3Tree:
        return dataclasses.replace(self, levels=level)

    def skeleton(self, rng: np.random.Generator) -> tuple[Skeleton, float]:
        """The skeleton (model units) and this tree's metres-per-unit scale."""
        skel = grow_skeleton(
            rng,
            variant=self.variant,
            levels=self.levels,
            trunk=self.trunk,
            angle_deg=self.angle_deg,
            ratio_side=self.ratio_side,
            ratio_centre=self.ratio_centre,
            divergence_deg=self.divergence_deg,
            radius0=self.radius0,
            radius_ratio=self.radius_ratio,
            sprout=self.sprout,
            twist_max_deg=self.twist_max_deg,
        )
        return skel, self.unit_m * float(clipped_normal(rng, 1.0, self.scale_sd))

    def grow(self, rng: np.random.Generator, *, branches: bool = False) -> TreeGeometry:
        skel, scale = self.skeleton(rng)
        centers, normals = skeleton_leaves(
            skel,
            rng,
            nodes=self.nodes,
            leaves_per_node=self.leaves_per_node,
            tip_leaves=self.tip_leaves,
            node_jitter=self.node_jitter,
            tip_jitter=self.tip_jitter,
            min_level=1 if self.levels > 0 or self.variant == "single" else 0,
        )
        radii = _leaf_radii(rng, self.leaf_radius_mean_m, self.leaf_radius_sd_m, len(centers))
        geo = TreeGeometry(centers * scale, normals, radii)
        if branches:
            geo = dataclasses.replace(
                geo,
                seg_start=skel.start * scale,
                seg_end=skel.end * scale,
                seg_radius=skel.radius * scale,
            )
        return geo


@dataclass(frozen=True)
class LppTree:
    """A seed 001 L++ tree: ``grammar`` names its grammar, a packaged name (``"tree4"``) or a
    file path; ``parsed`` is that grammar once read (:meth:`with_grammar`; reading it is
    ``hil_bridge.files.world``), which growing needs.

    Attributes:
        unit_m: metres per grammar unit (segment length 1).
        iterations: growth level override (``None``: the grammar's header).
        growth_jitter: apply the seed's ±1 growth-level draw.
        keep_prob: probability that a ``*`` command makes a leaf (seed: 0.5).
        angle_noise: relative sd of the ``& ^ \\ /`` angles and of the ``>`` narrowing (seed:
            0.1).
        leaf_size: ``"metres"`` (default): acoustic radius N(``leaf_radius_mean_m``,
            ``leaf_radius_sd_m``²) truncated at ±2σ (and ≥ 1 mm), metres, whatever ``unit_m``;
            ``"seed"``: the seed's rule, leaf length N(``seed_leaf_size``, (0.15
            ``seed_leaf_size``)²) clipped at ±2σ in grammar units, radius 0.3206 × length
            × ``unit_m`` (docs/world.md says why the default differs).
        seed_leaf_size: the seed's ``leafSize`` for this species (tree4..7: 1.5, 1.6, 1.1, 1.4).

    Branches (``grow(branches=True)``) have the seed's radius (:func:`~.lpp.branch_radii`):
    ``seg_radius`` is each segment's base radius in metres (its top is the reduction, 0.95 by
    default, times that). Their ``>`` draws come after every leaf draw, so asking for branches
    leaves the leaves unchanged.
    """

    grammar: str
    unit_m: float = 0.4
    iterations: int | None = None
    growth_jitter: bool = True
    keep_prob: float = 0.5
    angle_noise: float = 0.1
    leaf_radius_mean_m: float = 0.025
    leaf_radius_sd_m: float = 0.005
    leaf_size: Literal["metres", "seed"] = "metres"
    seed_leaf_size: float = 1.4
    parsed: Grammar | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if not self.unit_m > 0:
            raise ValueError(f"unit_m must be > 0, got {self.unit_m}")
        if self.iterations is not None and self.iterations < 0:
            raise ValueError(f"iterations must be >= 0, got {self.iterations}")
        if not (0.0 <= self.keep_prob <= 1.0):
            raise ValueError(f"keep_prob must be in [0, 1], got {self.keep_prob}")
        if not (0.0 <= self.angle_noise < 1.0):
            raise ValueError(f"angle_noise must be in [0, 1), got {self.angle_noise}")
        _check_leaf_radius(self.leaf_radius_mean_m, self.leaf_radius_sd_m)
        if self.leaf_size not in ("metres", "seed"):
            raise ValueError(f"leaf_size must be 'metres' or 'seed', got {self.leaf_size!r}")
        if not (self.seed_leaf_size > 0 and np.isfinite(self.seed_leaf_size)):
            raise ValueError(f"seed_leaf_size must be > 0, got {self.seed_leaf_size}")

    def with_grammar(self, grammar: Grammar) -> LppTree:
        """This tree with its grammar read (``grammar``: the parsed text of :attr:`grammar`)."""
        return dataclasses.replace(self, parsed=grammar)

    def rules(self) -> Grammar:
        """The parsed grammar; ``ValueError`` when it has not been read."""
        if self.parsed is None:
            raise ValueError(
                f"L++ grammar {self.grammar}: not read; give the tree its grammar "
                "(with_grammar, or hil_bridge.files.world.load_tree_model)"
            )
        return self.parsed

    def with_growth_level(self, level: int) -> LppTree:
        return dataclasses.replace(self, iterations=level, growth_jitter=False)

    def grow(self, rng: np.random.Generator, *, branches: bool = False) -> TreeGeometry:
        g = self.rules()
        nominal = g.iterations if self.iterations is None else self.iterations
        level = growth_level(nominal, rng, jitter=self.growth_jitter)
        seq, table = expand(g, level, rng)
        tr = interpret(seq, table, g.default_angle_deg, rng, angle_noise=self.angle_noise)
        keep = rng.random(tr.leaf_pos.shape[0]) < self.keep_prob
        pos, d = tr.leaf_pos[keep], tr.leaf_dir[keep]
        n = pos.shape[0]
        if self.leaf_size == "seed":
            size = self.seed_leaf_size
            radii = LEAF_DISC_RATIO * self.unit_m * clipped_normal(rng, size, 0.15 * size, n)
        else:
            radii = _leaf_radii(rng, self.leaf_radius_mean_m, self.leaf_radius_sd_m, n)
        bend = d[:, 1] / 4.0
        flat = d[:, 1] == 0.0
        if flat.any():
            bend[flat] = (rng.integers(0, 20, size=int(flat.sum())) - 10) / 100.0
        # minimal rotation +Y -> heading (skipped when nearly parallel, as in the seed)
        axis = np.stack([d[:, 2], np.zeros(n), -d[:, 0]], axis=1)
        s = np.linalg.norm(axis, axis=1)
        turn = s >= 1e-3
        khat = np.zeros_like(axis)
        khat[turn] = axis[turn] / s[turn, None]
        angle = np.where(turn, np.arctan2(s, d[:, 1]), 0.0)
        normal = rotate(np.tile([0.0, 0.0, 1.0], (n, 1)), khat, angle)
        centroid = np.stack([np.zeros(n), (3.01 - bend) / 8.0, bend / 4.0], axis=1)
        offset = rotate(centroid, khat, angle) * (radii / LEAF_DISC_RATIO)[:, None]
        centre = pos * self.unit_m + offset
        geo = TreeGeometry(_to_enu(centre), _to_enu(normal), radii)
        if branches:
            radius = branch_radii(seq, table, g.default_angle_deg, g.thickness_pct, rng,
                                  narrow_noise=self.angle_noise)
            geo = dataclasses.replace(
                geo,
                seg_start=_to_enu(tr.seg_start * self.unit_m),
                seg_end=_to_enu(tr.seg_end * self.unit_m),
                seg_radius=radius[:, 0] * self.unit_m,
            )
        return geo


def _to_enu(v: F64) -> F64:
    """L++ frame (x, y up, z) -> ENU (x, −z, y)."""
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)


TreeModel = GMT3Tree | LppTree

# Leaf radii of the L++ species keep the ratios of the seed's leafSize (tree4..7: 1.5, 1.6, 1.1,
# 1.4) around 2.5 cm: mean radius = leafSize x 2.5 cm / 1.4, sd = 20 % of the mean.
_R = 0.025 / 1.4

#: named tree models (species presets)
TREE_MODELS: dict[str, TreeModel] = {
    # seed 000 "maple" branching: 6-level forest variant, 14-21 m tall
    "maple": GMT3Tree(),
    # seed 000 single-tree variant (Fig 5a/b first-level branches), 1 unit = 2 m
    "maple-single": GMT3Tree(variant="single", unit_m=2.0, nodes=8, leaves_per_node=6),
    # stand-in for the missing hazelnut CAD (spec §2A.4): a short-stemmed, round GMT3 shrub,
    # ~3 m tall and ~3 m wide
    "hazelnut-bush": GMT3Tree(
        levels=5,
        trunk=0.25,
        angle_deg=30.0,
        ratio_side=0.85,
        ratio_centre=0.8,
        sprout=(0.0, 0.05),
        radius0=0.015,
        unit_m=2.5,
        leaf_radius_mean_m=0.03,
        leaf_radius_sd_m=0.006,
    ),
    # seed 001 species (spec §2B.2); unit_m chosen so heights fall in 5-25 m
    **{
        name: LppTree(name, unit_m=unit, leaf_radius_mean_m=size * _R,
                      leaf_radius_sd_m=0.2 * size * _R, seed_leaf_size=size)
        for name, unit, size in (
            ("tree4", 0.4, 1.5), ("tree5", 0.5, 1.6), ("tree6", 0.45, 1.1), ("tree7", 0.35, 1.4)
        )
    },
}


def get_tree_model(name: str) -> TreeModel:
    """The named tree model; unknown names raise ``ValueError`` listing the known ones."""
    try:
        return TREE_MODELS[name]
    except KeyError:
        known = sorted(TREE_MODELS)
        raise ValueError(f"unknown tree model {name!r}; expected one of {known}") from None
