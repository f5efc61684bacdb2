"""The forest world: L-system trees, IPP forests, leaves as a struct of arrays, tiles.

Public API (see ``docs/world.md``)::

    from sim_core.world import build_forest, get_preset, Leaves, TiledForest
    forest = build_forest(get_preset("seed001-fig9"), seed=1)
    forest.leaves.query_cone(apex, axis, half_angle_rad, r_max)
    world = TiledForest(spec, seed=1, tile_size_m=50.0, max_cache_bytes=256 << 20)
    near = world.leaves_near(point, radius_m)
"""

from sim_core.world.forest import (
    Forest,
    ForestSpec,
    KDESpec,
    KernelSpec,
    SpeciesSpec,
    TemplateSpec,
    build_forest,
    load_forest_spec,
)
from sim_core.world.leaves import Leaves
from sim_core.world.lpp import GrammarError
from sim_core.world.presets import get_preset, preset_names
from sim_core.world.tiles import TiledForest

__all__ = [
    "Forest",
    "ForestSpec",
    "GrammarError",
    "KDESpec",
    "KernelSpec",
    "Leaves",
    "SpeciesSpec",
    "TemplateSpec",
    "TiledForest",
    "build_forest",
    "get_preset",
    "load_forest_spec",
    "preset_names",
]
