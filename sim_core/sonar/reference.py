"""The fidelity interface and the ``reference`` fidelity (float64 direct sum, chunked).

Contract of a fidelity (:class:`Fidelity`), the one signature every implementation shares:

1. ``fid.run(scene, params, workspace) -> Band``: given the kept leaves of one ping
   (:class:`Scene`, from :func:`sim_core.sonar.model.prepare`), return the band spectra of
   every channel, with scratch arrays from ``workspace`` (:mod:`sim_core.sonar.workspace`).
2. It never builds an M x N array; memory is bounded for any number of leaves M.
3. ``Band.error_bound`` is the relative L2 error bound it ran at, or None if not reported.
4. ``fid.supports(params)`` returns None or the reason the fidelity cannot honour ``params``.
5. ``fid.leaf_budget(params)`` returns None or the :class:`LeafBudget` ``prepare`` plans the
   geometry with (the leaves left out are summarised in ``Scene.cut``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim_core.sonar.geometry import Scene
from sim_core.sonar.model import LeafBudget
from sim_core.sonar.params import EchoParams
from sim_core.sonar.weights import leaf_weights, window_at
from sim_core.sonar.workspace import Workspace

__all__ = ["Band", "Fidelity", "Reference", "direct_sum", "output_bins"]

#: complex elements per chunk of the direct sum (bounds memory at a few tens of MB)
CHUNK_ELEMENTS = 1 << 18


@dataclass(frozen=True, slots=True)
class Band:
    """Band spectra ``spectra`` (C, B) complex starting at FFT bin ``lo_bin``; ``error_bound``."""

    spectra: NDArray[np.complex128]
    lo_bin: int
    error_bound: float | None = None


def output_bins(scene: Scene, params: EchoParams) -> tuple[int, int]:
    """First and last received FFT bin holding signal (the band, Doppler-stretched if on)."""
    g = params.grid
    if not (params.doppler and params.moving) or scene.count == 0:
        return g.m0, g.m1
    lo = math.floor(g.m0 * float(scene.eta.min()))
    hi = math.ceil((g.m0 + g.count) * float(scene.eta.max()))
    if hi > g.n // 2:
        raise ValueError(
            f"Doppler shifts the band up to {hi * g.df:.0f} Hz, above fs/2 = "
            f"{params.fs / 2:.0f} Hz; raise fs"
        )
    return max(lo, 1), hi


class Fidelity(ABC):
    """One way of evaluating the echo sum (see the module contract)."""

    name: str = ""

    def supports(self, params: EchoParams) -> str | None:
        """None if ``params`` can be honoured, else the reason it cannot."""
        return None

    def leaf_budget(self, params: EchoParams) -> LeafBudget | None:
        """None, or the time budget and cost model the geometry pass plans with."""
        return None

    @abstractmethod
    def run(self, scene: Scene, params: EchoParams, workspace: Workspace) -> Band:
        """Band spectra of all channels for the kept leaves ``scene``."""


class Reference(Fidelity):
    """The binding definition: X_k = w_k sum_i A_ik exp(j phi_ik), float64, leaves in chunks.

    With Doppler (reference only) each leaf's window, leaf response and amplitude are taken at
    the emitted frequency f'/eta_i of received bin f' (see docs/sonar.md).
    """

    name = "reference"

    def run(self, scene: Scene, params: EchoParams, workspace: Workspace) -> Band:
        lo, hi = output_bins(scene, params)
        g = params.grid
        f_rx = np.arange(lo, hi + 1) * g.df
        n_f = f_rx.shape[0]
        C = scene.beta.shape[0]
        doppler = params.doppler and params.moving
        if not doppler:
            spectra = np.stack([direct_sum(scene, ch, params, workspace) for ch in range(C)])
            return Band(spectra * g.window, lo, None)
        out = np.zeros((C, n_f), dtype=np.complex128)
        chunk = max(1, CHUNK_ELEMENTS // n_f)
        for ch in range(C):
            for start in range(0, scene.count, chunk):
                sub = scene.select(np.arange(start, min(start + chunk, scene.count)))
                phase = (2.0 * np.pi) * sub.tau[ch][:, None] * f_rx
                eta = sub.eta[ch][:, None]
                f_emit = f_rx / eta
                w = leaf_weights(sub, ch, f_emit * sub.leaf_ratio[ch][:, None], params,
                                 workspace=workspace)
                w *= window_at(f_emit, params) / eta
                out[ch] += np.einsum("ij,ij->j", w, np.exp(-1j * phase))
        return Band(out, lo, None)


def direct_sum(
    scene: Scene, ch: int, params: EchoParams, workspace: Workspace
) -> NDArray[np.complex128]:
    """Unwindowed band sum of channel ``ch``, sum_i W_ik exp(-j 2 pi f_k tau_i), (B,), float64."""
    g = params.grid
    f = g.freqs
    out = np.zeros(g.count, dtype=np.complex128)
    chunk = max(1, CHUNK_ELEMENTS // g.count)
    for start in range(0, scene.count, chunk):
        sub = scene.select(np.arange(start, min(start + chunk, scene.count)))
        phase = (2.0 * np.pi) * sub.tau[ch][:, None] * f
        w = leaf_weights(sub, ch, f, params, workspace=workspace)
        out += np.einsum("ij,ij->j", w, np.exp(-1j * phase))
    return out
