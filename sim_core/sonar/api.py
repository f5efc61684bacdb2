"""``synthesize``: one ping -> :class:`Echo`, with the fidelity chosen by name from one table."""

from __future__ import annotations

from numpy.typing import ArrayLike

from sim_core.sonar.fast import Fast, Realtime
from sim_core.sonar.model import LeafSource, assemble, prepare
from sim_core.sonar.params import Beam, Echo, EchoParams
from sim_core.sonar.reference import Fidelity, Reference

__all__ = ["FIDELITIES", "synthesize"]

#: name -> implementation; every entry has the :class:`Fidelity` signature.
FIDELITIES: dict[str, Fidelity] = {
    "reference": Reference(),
    "fast": Fast(),
    "realtime": Realtime(),
}


def _resolve(fidelity: str | Fidelity) -> Fidelity:
    if isinstance(fidelity, Fidelity):
        return fidelity
    try:
        return FIDELITIES[fidelity]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown fidelity {fidelity!r}; expected one of {sorted(FIDELITIES)}"
        ) from None


def synthesize(
    leaves: LeafSource | tuple[ArrayLike, ArrayLike, ArrayLike],
    beam: Beam,
    params: EchoParams | None = None,
    *,
    fidelity: str | Fidelity = "fast",
) -> Echo:
    """Echo of ``leaves`` for one ping of ``beam``.

    ``leaves``: any object with ``centers`` (M,3) m, ``normals`` (M,3), ``radii`` (M,) m (e.g.
    ``sim_core.world.Leaves``) or a ``(centers, normals, radii)`` tuple; float32 is accepted.
    ``fidelity``: a name of :data:`FIDELITIES` or a :class:`Fidelity` instance. Returns samples
    (N,) float64 at ``params.fs`` (or (C, N) with ``params.ears``). Raises ValueError for
    invalid geometry/parameters (spec guards) or a switch the fidelity cannot honour.
    """
    params = EchoParams() if params is None else params
    if not isinstance(beam, Beam):
        raise TypeError(f"beam must be a sim_core.sonar.Beam, got {type(beam).__name__}")
    impl = _resolve(fidelity)
    reason = impl.supports(params)
    if reason is not None:
        raise ValueError(f"fidelity {impl.name!r} cannot run these parameters: {reason}")
    scene = prepare(leaves, beam, params, budget=impl.leaf_budget(params))
    band = impl.run(scene, params)
    samples = assemble(band.spectra, band.lo_bin, params)
    return Echo(samples, params.fs, scene.in_beam, scene.dropped, impl.name, band.error_bound)
