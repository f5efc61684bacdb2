"""The forest world: L-system trees, IPP forests, leaves as a struct of arrays, tiles.

Public API (see ``docs/world.md``)::

    from sim_core.world import build_forest, get_preset, Leaves, TiledForest
    forest = build_forest(get_preset("seed000-fig5d"), seed=1)
    forest.leaves.query_cone(apex, axis, half_angle_rad, r_max)
    world = TiledForest(spec, seed=1, files=files, tile_size_m=50.0, max_cache_bytes=256 << 20)
    near = world.leaves_near(point, radius_m)

A spec that names files (L++ grammars, tree maps, CAD templates; :func:`named_files`) is built
with what they hold, a :class:`ForestFiles` read by ``hil_bridge.files.world``.
"""

from sim_core.world.forest import Forest, build_forest
from sim_core.world.leaves import Leaves
from sim_core.world.lpp import GrammarError
from sim_core.world.presets import get_preset, preset_names
from sim_core.world.spec import (
    ForestFiles,
    ForestSpec,
    KDESpec,
    KernelSpec,
    SpeciesSpec,
    TemplateSpec,
    named_files,
)
from sim_core.world.tiles import TiledForest

__all__ = [
    "Forest",
    "ForestFiles",
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
    "named_files",
    "preset_names",
]
