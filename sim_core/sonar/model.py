"""The foliage echo model of ``spec/echo_model.md``: guards, beam selection, per-leaf terms.

Shared by every fidelity: :func:`prepare` applies the guards and the beam selection and returns
the per-leaf, frequency-independent quantities (:class:`Scene`); :func:`leaf_weights` evaluates
the per-leaf, per-frequency complex weight W_ik (everything except the delay phase and the
leaf-independent window); :func:`assemble` turns band spectra into time samples. Fidelities
differ only in how they evaluate sum_i W_ik exp(-j 2 pi f_k tau_i).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from sim_core.sonar.params import SIGMA_FACTOR, Beam, EchoParams
from sim_core.sonar.physics import (
    absorption_db_per_m,
    call_waveform,
    incident_freq_sigma,
    shading_factor,
)

__all__ = ["LeafSource", "Scene", "assemble", "leaf_weights", "prepare", "window_at"]

F64 = NDArray[np.float64]
C128 = NDArray[np.complex128]


@runtime_checkable
class LeafSource(Protocol):
    """Anything with leaf arrays: ``centers`` (M,3) m, ``normals`` (M,3), ``radii`` (M,) m."""

    @property
    def centers(self) -> ArrayLike: ...

    @property
    def normals(self) -> ArrayLike: ...

    @property
    def radii(self) -> ArrayLike: ...


@dataclass(frozen=True, slots=True)
class Scene:
    """Kept leaves of one ping, per channel c (C = number of ears, 1 if monostatic).

    ``a`` (M,) clamped radius m; ``beta`` (C,M) incidence angle rad; ``beam`` (C,M) the
    two-way beam gain S = S1(emitter) S1(ear); ``rest`` (C,M) shading / spreading factor;
    ``tau`` (C,M) two-way delay s; ``path`` (C,M) two-way path length m; ``cap`` (C,M)
    near-field cap r/2 m; ``theta2`` (C,2,M) squared off-axis angles of emitter and ear (for
    ``incident_freq``); ``leaf_ratio`` (C,M) leaf-frame / emitted frequency and ``eta`` (C,M)
    received / emitted frequency (both 1 without Doppler). ``q`` (M,) = S1 / r, the waterdrop
    metric (keep <=> q >= 1 / r0). ``dropped``: leaves removed by the guards.
    """

    a: F64
    beta: F64
    beam: F64
    rest: F64
    tau: F64
    path: F64
    cap: F64
    theta2: F64
    leaf_ratio: F64
    eta: F64
    q: F64
    dropped: int
    speed: float

    @property
    def count(self) -> int:
        return int(self.a.shape[0])

    def select(self, index: NDArray[np.intp] | slice) -> Scene:
        """The sub-scene of kept leaves ``index`` (ints into 0..count-1, or a slice: views)."""
        return Scene(
            a=self.a[index],
            beta=self.beta[:, index],
            beam=self.beam[:, index],
            rest=self.rest[:, index],
            tau=self.tau[:, index],
            path=self.path[:, index],
            cap=self.cap[:, index],
            theta2=self.theta2[:, :, index],
            leaf_ratio=self.leaf_ratio[:, index],
            eta=self.eta[:, index],
            q=self.q[index],
            dropped=self.dropped,
            speed=self.speed,
        )


def _leaf_arrays(
    leaves: LeafSource | tuple[ArrayLike, ArrayLike, ArrayLike],
) -> tuple[F64, F64, F64]:
    if isinstance(leaves, tuple):
        centers, normals, radii = leaves
    else:
        try:
            centers, normals, radii = leaves.centers, leaves.normals, leaves.radii
        except AttributeError:
            raise TypeError(
                "leaves must have centers/normals/radii arrays or be a (centers, normals, radii) "
                f"tuple, got {type(leaves).__name__}"
            ) from None
    c = np.asarray(centers, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    a = np.asarray(radii, dtype=np.float64)
    if c.ndim == 1 and c.size == 0:
        c = c.reshape(0, 3)
    if n.ndim == 1 and n.size == 0:
        n = n.reshape(0, 3)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"leaf centers must have shape (M, 3), got {c.shape}")
    if n.shape != c.shape:
        raise ValueError(f"leaf normals must have shape {c.shape}, got {n.shape}")
    if a.shape != (c.shape[0],):
        raise ValueError(f"leaf radii must have shape ({c.shape[0]},), got {a.shape}")
    return c, n, a


def _rowdot(x: F64, v: F64) -> F64:
    """x @ v for x (M,3), v (3,) without BLAS (OpenBLAS threads spin on a shared machine)."""
    return np.einsum("ij,j->i", x, v)


def _theta2(u: F64, axis: F64, seed2020: bool) -> F64:
    """Squared off-axis angle, rad^2, shape (M,): arccos(u.b)^2, or (seed2020) daz^2 + del^2."""
    if not seed2020:
        return np.arccos(np.clip(_rowdot(u, axis), -1.0, 1.0)) ** 2
    az = np.arctan2(u[:, 1], u[:, 0])
    el = np.arcsin(np.clip(u[:, 2], -1.0, 1.0))
    az0 = math.atan2(float(axis[1]), float(axis[0]))
    el0 = math.asin(float(np.clip(axis[2], -1.0, 1.0)))
    daz = np.mod(az - az0 + np.pi, 2.0 * np.pi) - np.pi
    return daz * daz + (el - el0) ** 2


def _ear_geometry(beam: Beam, params: EchoParams) -> list[tuple[F64, F64, float]]:
    """Per channel: receiver position (3,), beam axis (3,), sigma (rad)."""
    if not params.ears:
        return [(beam.position, beam.boresight, beam.sigma)]
    frame = beam.frame()
    out = []
    for ear in params.ears:
        pos = beam.position + np.asarray(ear.offset) @ frame
        cy, sy = math.cos(ear.yaw_rad), math.sin(ear.yaw_rad)
        cp, sp = math.cos(ear.pitch_rad), math.sin(ear.pitch_rad)
        axis = np.array([cp * cy, cp * sy, sp]) @ frame
        bw = beam.beamwidth_rad if ear.beamwidth_rad is None else ear.beamwidth_rad
        out.append((pos, axis / np.linalg.norm(axis), 0.5 * bw / SIGMA_FACTOR))
    return out


#: leaf sets at least this large are culled through their own ``query_ball`` (a k-d tree that
#: pays for its construction only when a large set is reused across pings); smaller sets, such
#: as the per-ping ``TiledForest.leaves_near`` result, are culled by the vectorised cone test
INDEX_MIN_LEAVES = 200_000


def _candidates(
    leaves: object, count: int, beam: Beam, reach: float
) -> NDArray[np.intp] | None:
    """Indices within ``reach`` of the sonar from the leaves' own spatial index, if worth it."""
    query = getattr(leaves, "query_ball", None)
    if query is None or count < INDEX_MIN_LEAVES:
        return None
    return np.asarray(query(beam.position, reach), dtype=np.intp)


def prepare(
    leaves: LeafSource | tuple[ArrayLike, ArrayLike, ArrayLike], beam: Beam, params: EchoParams
) -> Scene:
    """Apply the guards and the beam selection; compute per-leaf quantities (spec, all channels).

    Guards: leaves with a non-finite centre/normal/radius, a zero normal or r < r_min are dropped
    and counted; if the window cannot hold the farthest kept leaf (max delay + call length >=
    N / fs) a ValueError names the numbers. For INDEX_MIN_LEAVES or more leaves with a
    ``query_ball(point, r)`` method (``sim_core.world.Leaves``) only that ball is examined.
    """
    c, n, a = _leaf_arrays(leaves)
    v = params.speed
    r0 = params.selection_radius
    a0 = params.peak_amplitude
    cand = _candidates(leaves, c.shape[0], beam, r0 * max(a0, 1.0))
    if cand is not None:
        c, n, a = c[cand], n[cand], a[cand]
    ones = np.ones(3)
    d = c - beam.position
    with np.errstate(invalid="ignore", over="ignore"):
        finite = np.isfinite(_rowdot(d, ones) + _rowdot(n, ones) + a)
    nn2 = np.einsum("ij,ij->i", n, n)
    r2 = np.einsum("ij,ij->i", d, d)
    valid = finite & (nn2 > 0.0) & (r2 >= params.r_min**2)
    dropped = int(c.shape[0] - np.count_nonzero(valid))
    # Pre-cull before any transcendental: S1 >= r/r0 >= r_min/r0 bounds the off-axis angle.
    sigma = beam.sigma
    reach_angle = sigma * math.sqrt(2.0 * math.log(max(a0 * r0 / params.r_min, 1.0 + 1e-12)))
    proj = _rowdot(d, beam.boresight)
    cand_mask = valid & (r2 <= (r0 * a0) ** 2)
    if not params.seed2020 and reach_angle < math.pi:
        with np.errstate(invalid="ignore"):
            cand_mask &= proj >= (math.cos(reach_angle) - 1e-12) * np.sqrt(r2)
    if cand_mask.all():
        idx = np.arange(c.shape[0])
        r = np.sqrt(r2)
    else:
        idx = np.flatnonzero(cand_mask)
        r, d, proj = np.sqrt(r2[idx]), d[idx], proj[idx]
    if params.seed2020:
        th2 = _theta2(d / r[:, None], beam.boresight, True)
    else:
        th2 = np.arccos(np.clip(proj / r, -1.0, 1.0)) ** 2
    s1 = a0 * np.exp(-th2 / (2.0 * sigma * sigma))
    keep = r <= r0 * s1
    if keep.all():
        idx2 = idx
    else:
        sel = np.flatnonzero(keep)
        idx2 = idx[sel]
        d, r, th2, s1 = d[sel], r[sel], th2[sel], s1[sel]
    if idx2.shape[0] == c.shape[0]:
        nn = np.sqrt(nn2)
        a = np.maximum(a, params.a_min)
    else:
        n, nn = n[idx2], np.sqrt(nn2[idx2])
        a = np.maximum(a[idx2], params.a_min)
    nd = np.einsum("ij,ij->i", n, d) / nn
    m = r.shape[0]
    monostatic = not params.ears
    need_u = params.shading or not monostatic or (params.doppler and params.moving)
    u = d / r[:, None] if need_u else d
    vel = np.asarray(params.platform_velocity, dtype=np.float64)
    shade = np.ones(m)
    if params.shading and m > 1:
        shade = shading_factor(u, r, a, nd / r, params.shading_opacity)
    channels = _ear_geometry(beam, params)
    C = len(channels)
    beta = np.empty((C, m))
    beam_gain = np.empty((C, m))
    rest = np.empty((C, m))
    tau = np.empty((C, m))
    path = np.empty((C, m)) if params.absorption else _filled(0.0, C, m)
    cap = np.empty((C, m)) if params.near_field_cap else _filled(0.0, C, m)
    incident = params.beam_model == "incident_freq"
    theta2 = np.empty((C, 2, m)) if incident else _filled(0.0, C, 2, m)
    doppler = params.doppler and params.moving
    leaf_ratio = np.empty((C, m)) if doppler else _filled(1.0, C, m)
    eta = np.empty((C, m)) if doppler else _filled(1.0, C, m)
    t1 = r / v
    for ch, (pos, axis, sig) in enumerate(channels):
        if monostatic:
            dr, rr, th2r, s1r = d, r, th2, s1
            beta[ch] = np.arccos(np.clip(np.abs(nd) / r, 0.0, 1.0))
        else:
            dr = d + (beam.position - pos)
            rr = np.sqrt(np.einsum("ij,ij->i", dr, dr))
            rr = np.maximum(rr, params.r_min)
            ur = dr / rr[:, None]
            th2r = _theta2(ur, axis, params.seed2020)
            s1r = a0 * np.exp(-th2r / (2.0 * sig * sig))
            bis = u + ur
            bis_n = np.sqrt(np.einsum("ij,ij->i", bis, bis))
            ok = bis_n > 0.0
            bis = np.where(ok[:, None], bis / np.where(ok, bis_n, 1.0)[:, None], u)
            nhat_bis = np.abs(np.einsum("ij,ij->i", n, bis)) / nn
            beta[ch] = np.arccos(np.clip(nhat_bis, 0.0, 1.0))
        spread = 1.0 if (not params.spreading or params.seed2020) else 1.0 / (r * rr)
        beam_gain[ch] = s1 * s1r
        rest[ch] = shade * spread
        if incident:
            theta2[ch, 0] = th2
            theta2[ch, 1] = th2r
        if params.near_field_cap:
            cap[ch] = 0.5 * np.sqrt(r * rr)
        if params.absorption:
            path[ch] = r + rr
        if params.moving:
            q = dr - vel * t1[:, None]
            qq = np.einsum("ij,ij->i", q, q)
            qv = _rowdot(q, vel)
            vv = float(vel @ vel)
            s = qq / (qv + np.sqrt(qv * qv + (v * v - vv) * qq))
            tau[ch] = t1 + s
            if doppler:
                u_rx = (q - vel * s[:, None]) / (v * s)[:, None]
                leaf_ratio[ch] = v / (v - _rowdot(u, vel))
                eta[ch] = leaf_ratio[ch] * (v + _rowdot(u_rx, vel)) / v
        else:
            tau[ch] = (r + rr) / v
    if m:
        call_s = params.call.total_s if params.call is not None else 0.0
        window_s = params.samples / params.fs
        t_max = float(tau.max()) + call_s
        if not t_max < window_s:
            far = float(r.max())
            need = math.ceil(t_max * params.fs) + 1
            raise ValueError(
                f"window of {params.samples} samples ({window_s * 1e3:.3f} ms) cannot hold the "
                f"farthest kept leaf (r = {far:.3f} m, echo ends at {t_max * 1e3:.3f} ms); "
                f"use samples >= {need} (and band edges on bins) or a higher threshold_db"
            )
    return Scene(
        a=a,
        beta=beta,
        beam=beam_gain,
        rest=rest,
        tau=tau,
        path=path,
        cap=cap,
        theta2=theta2,
        leaf_ratio=leaf_ratio,
        eta=eta,
        q=s1 / r,
        dropped=dropped,
        speed=v,
    )


def _filled(value: float, *shape: int) -> F64:
    """A read-only broadcast array of ``value`` (no memory per leaf) for unused fields."""
    return np.broadcast_to(np.float64(value), shape)


def _erf_fast(x: NDArray[np.floating]) -> NDArray[np.floating]:
    """erf via Abramowitz & Stegun 7.1.26 (|error| <= 1.5e-7), SIMD-friendly for float32."""
    ax = np.abs(x)
    dt = x.dtype.type
    t = dt(1.0) / (dt(1.0) + dt(0.3275911) * ax)
    poly = dt(1.061405429) * t + dt(-1.453152027)
    for coef in (1.421413741, -0.284496736, 0.254829592):
        poly *= t
        poly += dt(coef)
    poly *= t
    y = dt(1.0) - poly * np.exp(-ax * ax)
    return np.copysign(y, x)


def leaf_weights(
    scene: Scene,
    ch: int,
    f_leaf: ArrayLike,
    params: EchoParams,
    *,
    single: bool = False,
    freq_major: bool = False,
) -> NDArray[np.complexfloating]:
    """Per-leaf, per-frequency weight W = A exp(-j psi) (no delay phase, no window), (M, F).

    ``f_leaf`` Hz is the frequency the leaf sees, shape (F,) or (M, F). A = g0 S L / k / r^2
    (spec), with the opt-in absorption, near-field cap and incident-frequency beam applied.
    ``single=True`` evaluates in float32 with a 1.5e-7 erf approximation (fast fidelities;
    relative error ~1e-6), returning complex64. ``freq_major=True`` (``f_leaf`` of shape (F,)
    only) returns the transpose, (F, M), C-contiguous.
    """
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
    a: Any = a64.astype(dt)
    beta: Any = leaf(scene.beta[ch].astype(dt))
    c = kk * a
    p1 = dt(0.5003) * c * c + dt(0.6867)
    # c^p = a^p k^p: the powers are taken per leaf and per frequency, not per (leaf, frequency)
    p2 = (dt(0.3999) * a64**-0.9065).astype(dt) * (kk64**-0.9065).astype(dt) + dt(0.9979)
    lb = np.maximum(dt(0.0), p1 * np.cos(p2 * beta))
    apsi = (dt(0.9824) * a64**0.3523).astype(dt) * (kk64**0.3523).astype(dt) - dt(0.9459)
    z = apsi * (dt(1.57) - beta)
    psi = (_erf_fast(z) if single else erf(z)) - dt(2.6343)
    if params.beam_model == "incident_freq":
        sig = incident_freq_sigma(f_axis).astype(dt)
        th = leaf((scene.theta2[ch, 0] + scene.theta2[ch, 1]).astype(dt))
        a0 = params.peak_amplitude
        gain: Any = dt(a0 * a0) * np.exp(-th / (2.0 * sig * sig))
        gain = gain * leaf(scene.rest[ch].astype(dt))
    else:
        gain = leaf((scene.beam[ch] * scene.rest[ch]).astype(dt))
    amp = dt(params.g0) * lb / kk
    if params.near_field_cap:
        amp = np.minimum(amp, leaf(scene.cap[ch].astype(dt)))
    amp = amp * gain
    if params.absorption:
        alpha = absorption_db_per_m(
            f_axis, params.temperature_c, params.humidity_pct, params.pressure_kpa
        ).astype(dt)
        amp = amp * np.exp(alpha * leaf(scene.path[ch].astype(dt)) * dt(-math.log(10.0) / 20.0))
    out = np.empty(amp.shape, dtype=np.complex64 if single else np.complex128)
    out.real = amp * np.cos(psi)
    out.imag = -amp * np.sin(psi)
    return out


def window_at(freq: F64, params: EchoParams) -> F64:
    """Continuous periodic-Hann band window at emitted frequencies ``freq`` Hz (0 outside)."""
    g = params.grid
    x = (np.asarray(freq) / g.df - g.m0) / g.count
    inside = (x >= 0.0) & (x <= 1.0)
    return np.where(inside, 0.5 * (1.0 - np.cos(2.0 * np.pi * x)), 0.0)


def assemble(spectra: C128, lo_bin: int, params: EchoParams) -> F64:
    """Band spectra (C, B) starting at bin ``lo_bin`` -> time samples (C, N) or (N,).

    h = 2 irfft(H, N) with H zero outside the band; with a call, H is multiplied by the call's
    spectrum first (echo = call * impulse response).
    """
    n = params.samples
    C, B = spectra.shape
    H = np.zeros((C, n // 2 + 1), dtype=np.complex128)
    H[:, lo_bin : lo_bin + B] = spectra
    if params.call is not None:
        H[:, lo_bin : lo_bin + B] *= np.fft.rfft(call_waveform(params.call, params.fs), n=n)[
            lo_bin : lo_bin + B
        ]
    h = 2.0 * np.fft.irfft(H, n=n, axis=-1)
    return h[0] if not params.ears else h
