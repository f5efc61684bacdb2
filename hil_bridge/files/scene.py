"""Scene files: a scene YAML file (or mapping) -> a :class:`sim_core.scene.Scene` given the
readers of the files it names (its swarm's law file, the grammars, tree maps and templates of
its forest; logged paths through the ``trajectory_reader`` the caller passes). The schema is
:mod:`sim_core.scene.spec`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hil_bridge.files.config import load_yaml
from hil_bridge.files.soaring import load_law
from hil_bridge.files.world import load_forest_files
from sim_core.config import ConfigError, from_dict
from sim_core.scene import Scene, SceneSpec, TrajectoryReader

__all__ = ["load_scene"]


def load_scene(
    source: str | Path | Mapping[str, Any] | SceneSpec,
    *,
    trajectory_reader: TrajectoryReader | None = None,
) -> Scene:
    """Build a :class:`Scene` from a YAML path, a mapping or a :class:`SceneSpec` (validated),
    with :func:`hil_bridge.files.soaring.load_law` and
    :func:`hil_bridge.files.world.load_forest_files` as its law and forest readers.

    ``trajectory_reader`` reads the ``kind: file`` paths
    (``hil_bridge.recording.logs.load_trajectory``). Errors of a file name it.
    """
    if isinstance(source, SceneSpec):
        return _scene(source, trajectory_reader)
    if isinstance(source, Mapping):
        return _scene(from_dict(SceneSpec, source, path="scene"), trajectory_reader)
    data = load_yaml(source)
    try:
        return _scene(from_dict(SceneSpec, data), trajectory_reader)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def _scene(spec: SceneSpec, trajectory_reader: TrajectoryReader | None) -> Scene:
    return Scene(spec, trajectory_reader=trajectory_reader, law_reader=load_law,
                 forest_reader=load_forest_files)
