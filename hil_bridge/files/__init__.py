"""File formats of the world: YAML configs, scene/forest/law/grid files, npz leaves and forests,
IPP CSV, L++ grammars, CAD meshes, traces, and the package data behind presets.

``sim_core`` takes and returns arrays, dataclasses, dicts and strings; the readers and writers
that turn files into those (and back) live here: ``config`` (text, YAML, ``.npz`` archives,
``KEY=VALUE`` overrides), ``world`` (forest specs and the files they name, leaves and forests as
``.npz``, tree maps, grammars, CAD templates, packaged tree models), ``soaring`` (law and grid
files, traces as ``.npz``/CSV, sweep run keys) and ``scene`` (scene files, and a
:class:`sim_core.scene.Scene` given the readers of its forest and law). Package data: ``data/``.

May import: ``sim_core``, ``hil_bridge.errors`` and ``hil_bridge.outputs`` only.
"""
