"""The per-leaf, per-frequency weight of the echo model (``docs/spec/echo_model.md``) and the
band window.

:func:`leaf_weights` evaluates W_ik = A_ik exp(-j psi_ik) of every kept leaf i of a
:class:`~sim_core.sonar.geometry.Scene` at frequencies f_k: the leaf's scattering (L, psi from
c = k a and the incidence angle), the beam gain and spreading, and the opt-in absorption,
near-field cap and incident-frequency beam; everything but the delay phase and the
leaf-independent window (:func:`window_at`). The fidelities differ only in how they evaluate
sum_i W_ik exp(-j 2 pi f_k tau_i).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from sim_core.sonar.geometry import Scene
from sim_core.sonar.params import EchoParams
from sim_core.sonar.physics import absorption_db_per_m, incident_freq_sigma
from sim_core.sonar.workspace import Workspace

__all__ = ["leaf_weights", "window_at"]

F64 = NDArray[np.float64]


def _erf_fast(x: NDArray[np.floating], ws: Workspace) -> NDArray[np.floating]:
    """erf via Abramowitz & Stegun 7.1.26 (|error| <= 1.5e-7), SIMD-friendly for float32.

    Overwrites and returns ``x``.
    """
    dt = x.dtype.type
    ax = np.abs(x, out=ws.array("erf_ax", x.shape, dt))
    t = np.multiply(ax, dt(0.3275911), out=ws.array("erf_t", x.shape, dt))
    t += dt(1.0)
    np.reciprocal(t, out=t)
    poly = np.multiply(t, dt(1.061405429), out=ws.array("erf_poly", x.shape, dt))
    poly += dt(-1.453152027)
    for coef in (1.421413741, -0.284496736, 0.254829592):
        poly *= t
        poly += dt(coef)
    poly *= t
    ax *= ax
    np.negative(ax, out=ax)
    np.exp(ax, out=ax)
    poly *= ax
    np.subtract(dt(1.0), poly, out=poly)
    return np.copysign(poly, x, out=x)


def leaf_weights(
    scene: Scene,
    ch: int,
    f_leaf: ArrayLike,
    params: EchoParams,
    *,
    single: bool = False,
    freq_major: bool = False,
    phase: NDArray[np.floating] | None = None,
    out: NDArray[np.complexfloating] | None = None,
    workspace: Workspace,
) -> NDArray[np.complexfloating]:
    """Per-leaf, per-frequency weight W = A exp(-j psi) (no delay phase, no window), (M, F).

    ``f_leaf`` Hz is the frequency the leaf sees, shape (F,) or (M, F). A = g0 S L / k / r^2
    (spec), with the opt-in absorption, near-field cap and incident-frequency beam applied.
    ``single=True`` evaluates in float32 with a 1.5e-7 erf approximation (fast fidelities;
    relative error ~1e-6), returning complex64. ``freq_major=True`` (``f_leaf`` of shape (F,)
    only) returns the transpose, (F, M). ``phase`` (M,) rad, if given, multiplies leaf i by
    exp(-j phase_i); ``out`` receives the result (a complex array of the result's shape). The
    temporaries are ``workspace`` arrays; the result never is one (unless given as ``out``).
    """
    ws = workspace
    dt: Any = np.float32 if single else np.float64
    v = scene.speed
    f = np.asarray(f_leaf, dtype=np.float64)
    if freq_major:
        if f.ndim != 1:
            raise ValueError(f"freq_major needs f_leaf of shape (F,), got {f.shape}")

        def leaf(x: NDArray[Any]) -> Any:
            return x[None, :]

        f_axis = f[:, None]
    else:

        def leaf(x: NDArray[Any]) -> Any:
            return x[:, None]

        f_axis = f
    kk64 = (2.0 * np.pi / v) * f_axis
    kk: Any = kk64.astype(dt)
    a64 = leaf(scene.a)
    beta: Any = leaf(scene.beta[ch].astype(dt))
    shape = np.broadcast_shapes(kk.shape, a64.shape)
    c = np.multiply(kk, a64.astype(dt), out=ws.array("c", shape, dt))
    p1 = np.multiply(dt(0.5003), c, out=ws.array("p1", shape, dt))
    p1 *= c
    p1 += dt(0.6867)
    # c^p = a^p k^p: the powers are taken per leaf and per frequency, not per (leaf, frequency)
    if single:
        # per-leaf powers in float32 through one logarithm (they are rounded to float32 anyway)
        log_a = np.log(a64.astype(dt))
        ap: Any = np.exp(log_a * dt(-0.9065))
        ap *= dt(0.3999)
        bp: Any = np.exp(log_a * dt(0.3523))
        bp *= dt(0.9824)
    else:
        ap = dt(0.3999) * a64**-0.9065
        bp = dt(0.9824) * a64**0.3523
    lb = np.multiply(ap, (kk64**-0.9065).astype(dt), out=ws.array("lb", shape, dt))
    lb += dt(0.9979)
    lb *= beta
    np.cos(lb, out=lb)
    lb *= p1
    np.maximum(lb, dt(0.0), out=lb)
    psi = np.multiply(bp, (kk64**0.3523).astype(dt), out=ws.array("psi", shape, dt))
    psi -= dt(0.9459)
    psi *= dt(1.57) - beta
    if single:
        _erf_fast(psi, ws)
    else:
        erf(psi, out=psi)
    psi -= dt(2.6343)
    if params.beam_model == "incident_freq":
        sig = incident_freq_sigma(f_axis).astype(dt)
        th = leaf((scene.theta2[ch, 0] + scene.theta2[ch, 1]).astype(dt))
        a0 = params.peak_amplitude
        gain: Any = dt(a0 * a0) * np.exp(-th / (2.0 * sig * sig))
        gain = gain * leaf(scene.rest[ch].astype(dt))
    else:
        gain = leaf(scene.beam[ch].astype(dt))
    amp = lb
    amp *= dt(params.g0)
    amp /= kk
    if params.near_field_cap:
        np.minimum(amp, leaf(scene.cap[ch].astype(dt)), out=amp)
    amp *= gain
    if params.absorption:
        alpha = absorption_db_per_m(
            f_axis, params.temperature_c, params.humidity_pct, params.pressure_kpa
        ).astype(dt)
        amp *= np.exp(alpha * leaf(scene.path[ch].astype(dt)) * dt(-math.log(10.0) / 20.0))
    if phase is not None:
        psi += leaf(phase.astype(dt, copy=False))
    if out is None:
        out = np.empty(amp.shape, dtype=np.complex64 if single else np.complex128)
    trig = np.cos(psi, out=ws.array("trig", shape, dt))
    np.multiply(amp, trig, out=out.real)
    np.sin(psi, out=trig)
    np.negative(amp, out=amp)
    np.multiply(amp, trig, out=out.imag)
    return out


def window_at(freq: F64, params: EchoParams) -> F64:
    """Continuous periodic-Hann band window at emitted frequencies ``freq`` Hz (0 outside)."""
    g = params.grid
    x = (np.asarray(freq) / g.df - g.m0) / g.count
    inside = (x >= 0.0) & (x <= 1.0)
    return np.where(inside, 0.5 * (1.0 - np.cos(2.0 * np.pi * x)), 0.0)
