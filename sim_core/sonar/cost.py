"""What one echo costs: the cost model of the echo path (docs/sonar.md, "Cost model").

An echo of a sonar whose query ball holds ``N`` leaves (gathered from the forest's tiles and
examined by the range / cone pre-cull), ``C`` of which pass the pre-cull (candidates), ``T``
of those given the off-axis / waterdrop test and ``S`` synthesised, costs

    t = overhead + gather·N + examined·N + candidate·C + selected·T + leaf·S      (seconds)

(``fast`` tests every candidate and synthesises every selected leaf; ``realtime`` plans ``T``
and ``S`` so that ``t`` fits its budget: :class:`sim_core.sonar.model.LeafBudget` uses these
constants). Before an echo is computed only ``N`` and the beam are known; :meth:`EchoCost.
estimate` predicts ``C = N·fill·(1 − cos ρ)/2`` from the fraction of the sphere inside the
pre-cull cone of half-angle ρ (``fill`` > 1 when the foliage is denser in front of the sonar
than around it) and ``S = C·kept``. The synthesis constants are the ``realtime`` calibration
(``python -m bench sonar``); ``python -m bench multisonar`` checks the whole model, gathering
included, on the 8-sonar scene (docs/sonar.md, "Cost model"); a scheduler scales it by its own
measured ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["COST", "EchoCost"]


@dataclass(frozen=True, slots=True)
class EchoCost:
    """Seconds per echo and per leaf (module docstring)."""

    overhead_s: float = 1.0e-3
    gather_s: float = 3.5e-8
    per_examined_s: float = 1.5e-8
    per_candidate_s: float = 2.0e-8
    per_selected_s: float = 2.5e-8
    per_leaf_s: float = 6.0e-8
    fill: float = 1.0
    kept: float = 0.5

    def __post_init__(self) -> None:
        for name in ("overhead_s", "gather_s", "per_examined_s", "per_candidate_s",
                     "per_selected_s", "fill", "kept"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"EchoCost.{name}: expected a finite number >= 0, got {value!r}")
        if not (math.isfinite(self.per_leaf_s) and self.per_leaf_s > 0):
            raise ValueError(f"EchoCost.per_leaf_s: expected > 0, got {self.per_leaf_s!r}")

    def seconds(
        self, examined: int, candidates: int, tested: int, synthesised: int, gathered: int = 0
    ) -> float:
        """The model's time for an echo with these counts (``gathered`` leaves from tiles)."""
        return (self.overhead_s + self.gather_s * gathered + self.per_examined_s * examined
                + self.per_candidate_s * candidates + self.per_selected_s * tested
                + self.per_leaf_s * synthesised)

    def estimate(self, in_range: int, cone_half_angle_rad: float, *, gathered: bool = False
                 ) -> float:
        """Predicted ``fast`` echo time with ``in_range`` leaves in the query ball and a
        pre-cull cone of ``cone_half_angle_rad`` (``gathered``: add their gathering)."""
        share = min(1.0, self.fill * (1.0 - math.cos(min(cone_half_angle_rad, math.pi))) / 2.0)
        candidates = in_range * share
        return self.seconds(in_range, round(candidates), round(candidates),
                            round(candidates * self.kept), in_range if gathered else 0)


#: the measured constants (docs/sonar.md), used by ``realtime`` and the server's echo deadlines
COST = EchoCost()
