"""Foliage biosonar echoes (seed 000): the docs/spec/echo_model.md reference and fast fidelities.

Public API: :class:`EchoParams`, :class:`Beam`, :class:`Ear`, :class:`Call`, :class:`Echo`,
:func:`synthesize`, :data:`FIDELITIES`, :func:`to_baseband`, :class:`Workspace`. See
docs/sonar.md.
"""

from sim_core.sonar.api import FIDELITIES, synthesize
from sim_core.sonar.baseband import from_baseband, to_baseband
from sim_core.sonar.fast import Fast, Realtime
from sim_core.sonar.model import LeafSource
from sim_core.sonar.params import Beam, Call, Ear, Echo, EchoParams
from sim_core.sonar.reference import Fidelity, Reference
from sim_core.sonar.workspace import Workspace

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
