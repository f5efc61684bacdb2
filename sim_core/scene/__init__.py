"""Scenes: what the simulation server owns, as plain data (:mod:`sim_core.scene.spec`: the
:class:`SceneSpec` and its sections, with the scene file's schema) and as a :class:`Scene` that
builds only the parts a scene asks for (:mod:`sim_core.scene.runtime`). Scene files are read by
``hil_bridge.files.scene.load_scene``.
"""

from sim_core.scene.runtime import ForestReader, LawReader, Scene, TrajectoryReader
from sim_core.scene.spec import (
    ClockSpec,
    EarSpec,
    ForestSceneSpec,
    PathSpec,
    SceneSpec,
    SonarSpec,
    SwarmSceneSpec,
    VehicleSpec,
)

__all__ = [
    "ClockSpec",
    "EarSpec",
    "ForestReader",
    "ForestSceneSpec",
    "LawReader",
    "PathSpec",
    "Scene",
    "SceneSpec",
    "SonarSpec",
    "SwarmSceneSpec",
    "TrajectoryReader",
    "VehicleSpec",
]
