"""``synthesize``: one ping -> :class:`Echo`, with the fidelity chosen by name from one table.

The pipeline: :func:`~sim_core.sonar.model.prepare` (guards, beam selection, per-leaf terms),
the fidelity's band spectra (:meth:`Fidelity.run`), then :func:`assemble` (time samples).
"""

from __future__ import annotations

import contextlib

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.sonar.fast import Fast, Realtime
from sim_core.sonar.model import LeafSource, prepare
from sim_core.sonar.params import Beam, Echo, EchoParams
from sim_core.sonar.physics import call_waveform
from sim_core.sonar.reference import Fidelity, Reference
from sim_core.sonar.workspace import Workspace, borrowed

__all__ = ["FIDELITIES", "assemble", "synthesize"]

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
    workspace: Workspace | None = None,
) -> Echo:
    """Echo of ``leaves`` for one ping of ``beam``.

    ``leaves``: any object with ``centers`` (M,3) m, ``normals`` (M,3), ``radii`` (M,) m (e.g.
    ``sim_core.world.Leaves``) or a ``(centers, normals, radii)`` tuple; float32 is accepted.
    ``fidelity``: a name of :data:`FIDELITIES` or a :class:`Fidelity` instance. Returns samples
    (N,) float64 at ``params.fs`` (or (C, N) with ``params.ears``). Raises ValueError for
    invalid geometry/parameters (spec guards) or a switch the fidelity cannot honour.
    ``workspace``: the scratch memory to use (:mod:`sim_core.sonar.workspace`; never shared by
    two calls at once), else an idle one of the process is borrowed for the call.
    """
    params = EchoParams() if params is None else params
    if not isinstance(beam, Beam):
        raise TypeError(f"beam must be a sim_core.sonar.Beam, got {type(beam).__name__}")
    impl = _resolve(fidelity)
    reason = impl.supports(params)
    if reason is not None:
        raise ValueError(f"fidelity {impl.name!r} cannot run these parameters: {reason}")
    with borrowed() if workspace is None else contextlib.nullcontext(workspace) as ws:
        scene = prepare(leaves, beam, params, budget=impl.leaf_budget(params), workspace=ws)
        band = impl.run(scene, params, ws)
    samples = assemble(band.spectra, band.lo_bin, params)
    return Echo(samples, params.fs, scene.in_beam, scene.dropped, impl.name, band.error_bound)


def assemble(
    spectra: NDArray[np.complex128], lo_bin: int, params: EchoParams
) -> NDArray[np.float64]:
    """Band spectra (C, B) starting at bin ``lo_bin`` -> time samples (C, N) or (N,).

    h = 2 irfft(H, N) with H zero outside the band; with a call, H is multiplied by the call's
    spectrum first (echo = call * impulse response). The transform runs in the spectra's
    precision (complex64 from the single-precision ``fast``: twice as fast, and its rounding,
    ~1e-7 of the echo's L2 norm, is inside that fidelity's float32 error floor); the samples
    are float64 either way.
    """
    n = params.samples
    C, B = spectra.shape
    H = np.zeros((C, n // 2 + 1), dtype=spectra.dtype)
    H[:, lo_bin : lo_bin + B] = spectra
    if params.call is not None:
        H[:, lo_bin : lo_bin + B] *= np.fft.rfft(call_waveform(params.call, params.fs), n=n)[
            lo_bin : lo_bin + B
        ]
    h = np.fft.irfft(H, n=n, axis=-1).astype(np.float64, copy=False)
    h *= 2.0
    return h[0] if not params.ears else h
