"""Foliage biosonar echoes (seed 000): the docs/spec/echo_model.md reference and fast fidelities.

Public API: :class:`EchoParams`, :class:`Beam`, :class:`Ear`, :class:`Call`, :class:`Echo`,
:func:`synthesize`, :data:`FIDELITIES`, :func:`to_baseband`, :class:`Workspace`. See
docs/sonar.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sim_core.sonar.api import FIDELITIES, synthesize
    from sim_core.sonar.baseband import from_baseband, to_baseband
    from sim_core.sonar.fast import Fast, Realtime
    from sim_core.sonar.model import LeafSource
    from sim_core.sonar.params import Beam, Call, Ear, Echo, EchoParams
    from sim_core.sonar.reference import Fidelity, Reference
    from sim_core.sonar.workspace import Workspace

#: where each public name lives: imported when first asked for (PEP 562), so a process that
#: only converts to baseband (the serial adapter) does not import the echo simulator, its
#: scipy.spatial and its numba kernels (0.4 s a process)
_HOME = {
    "FIDELITIES": "api", "synthesize": "api", "from_baseband": "baseband",
    "to_baseband": "baseband", "Fast": "fast", "Realtime": "fast", "LeafSource": "model",
    "Beam": "params", "Call": "params", "Ear": "params", "Echo": "params",
    "EchoParams": "params", "Fidelity": "reference", "Reference": "reference",
    "Workspace": "workspace",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    module: Any
    if home == "baseband":
        from sim_core.sonar import baseband

        module = baseband
    elif home == "params":
        from sim_core.sonar import params

        module = params
    elif home is not None:  # the echo simulator itself
        from sim_core.sonar import api, fast, model, reference, workspace

        module = {"api": api, "fast": fast, "model": model, "reference": reference,
                  "workspace": workspace}[home]
    else:
        raise AttributeError(f"module 'sim_core.sonar' has no attribute {name!r}")
    value = getattr(module, name)
    globals()[name] = value
    return value


__all__ = [
    "FIDELITIES",
    "Beam",
    "Call",
    "Ear",
    "Echo",
    "EchoParams",
    "Fast",
    "Fidelity",
    "LeafSource",
    "Realtime",
    "Reference",
    "Workspace",
    "from_baseband",
    "synthesize",
    "to_baseband",
]
