"""The per-leaf terms of the kept leaves of one ping (``docs/spec/echo_model.md``): the
:class:`Scene` every fidelity sums.

For each kept leaf and channel (the emitter's own, or each ear): the incidence angle, the
two-way beam gain with the spreading and shading factor, the two-way delay (moving platform
included), the path length for absorption, the near-field cap and the Doppler ratios; computed
by :func:`leaf_terms` in blocks of GEOMETRY_BLOCK leaves from what the beam selection
(:func:`sim_core.sonar.model.prepare`) kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim_core.sonar.params import SIGMA_FACTOR, Beam, EchoParams
from sim_core.sonar.physics import shading_factor
from sim_core.sonar.seedbeam import off_axis

__all__ = ["GEOMETRY_BLOCK", "Cut", "Kept", "Scene", "leaf_terms", "off_axis_squared"]

F64 = NDArray[np.float64]

#: leaves per block of the geometry pass: temporaries of 128 KiB stay in cache and in the
#: allocator's free lists (whole-array temporaries of 1e5 leaves are fresh pages each time,
#: which cost more than the arithmetic on them)
GEOMETRY_BLOCK = 16384


@dataclass(frozen=True, slots=True)
class Cut:
    """Selected leaves left out of the synthesis by a :class:`~sim_core.sonar.model.LeafBudget`
    (``realtime``).

    ``count`` leaves; ``amax`` (C,) = sqrt(sum_i max_f |W_i(f)|^2) over them per channel, with
    max_f |W_i| bounded by g0 P1(k_hi a_i) S_i / (k_lo r_i r_ear,i) (the random-phase norm of
    their spectrum before the window, see :class:`sim_core.sonar.fast.Realtime`).
    """

    count: int
    amax: F64


@dataclass(frozen=True, slots=True)
class Scene:
    """Kept leaves of one ping, per channel c (C = number of ears, 1 if monostatic).

    ``a`` (M,) clamped radius m; ``beta`` (C,M) incidence angle rad; ``beam`` (C,M) the
    two-way beam gain S = S1(emitter) S1(ear) times ``rest``, the shading / spreading factor,
    except with ``beam_model="incident_freq"`` (S then depends on f): there ``beam`` is S at
    the fixed beamwidth and ``rest`` (C,M) that factor, otherwise ``rest`` is all ones;
    ``tau`` (C,M) two-way delay s; ``path`` (C,M) two-way path length m; ``cap`` (C,M)
    near-field cap r/2 m; ``theta2`` (C,2,M) squared off-axis angles of emitter and ear (for
    ``incident_freq``); ``leaf_ratio`` (C,M) leaf-frame / emitted frequency and ``eta`` (C,M)
    received / emitted frequency (both 1 without Doppler). ``dropped``: leaves removed by the
    guards; ``in_beam``: leaves the beam selects (the kept leaves plus ``cut``, those a
    :class:`~sim_core.sonar.model.LeafBudget` left out; under a range cut the untested
    candidates are counted, so it is then an upper bound).
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
    dropped: int
    speed: float
    in_beam: int
    cut: Cut

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
            dropped=self.dropped,
            speed=self.speed,
            in_beam=self.in_beam,
            cut=self.cut,
        )


@dataclass(frozen=True, slots=True)
class Kept:
    """The leaves the beam selection kept: rows ``index`` (K,) of the leaf arrays, and theirs:
    range ``r`` (K,) m, squared off-axis angle ``theta2`` (K,) rad^2 (the spec's, or the
    seed2020 az/el form), emitter gain ``s1`` (K,) and unit normal dotted with the offset
    ``nd`` (K,) m."""

    index: NDArray[np.intp]
    r: F64
    theta2: F64
    s1: F64
    nd: F64

    @property
    def count(self) -> int:
        return int(self.index.shape[0])

    def select(self, rows: NDArray[np.intp]) -> Kept:
        """The kept leaves at positions ``rows`` of these."""
        return Kept(self.index[rows], self.r[rows], self.theta2[rows], self.s1[rows],
                    self.nd[rows])


def _rowdot(x: F64, v: F64) -> F64:
    """x @ v for x (M,3), v (3,) without BLAS (OpenBLAS threads spin on a shared machine)."""
    return np.einsum("ij,j->i", x, v)


def off_axis_squared(u: F64, axis: F64, params: EchoParams) -> F64:
    """Squared off-axis angle, rad^2, (M,), of leaves in unit directions ``u`` (M,3) from a beam
    along unit ``axis``: arccos(u.b)^2, or with ``seed2020`` daz^2 + del^2 (exact or on the
    seed's grid, :mod:`sim_core.sonar.seedbeam`; these need only the direction, so any positive
    multiple of ``u`` gives the same)."""
    if not params.seed2020:
        return np.arccos(np.clip(_rowdot(u, axis), -1.0, 1.0)) ** 2
    daz, dele = off_axis(u[:, 0], u[:, 1], u[:, 2], axis, params.beam_lookup or "exact")
    return daz * daz + dele * dele


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


def _filled(value: float, *shape: int) -> F64:
    """A read-only broadcast array of ``value`` (no memory per leaf) for unused fields."""
    return np.broadcast_to(np.float64(value), shape)


def leaf_terms(
    c: F64,
    n: F64,
    a: F64,
    kept: Kept,
    beam: Beam,
    params: EchoParams,
    *,
    dropped: int,
    in_beam: int,
    cut: Cut,
) -> Scene:
    """The :class:`Scene` of the ``kept`` rows of leaf centres ``c`` (M,3) m, normals ``n``
    (M,3) and radii ``a`` (M,) m, all channels (``dropped``, ``in_beam``, ``cut``: what the
    selection counted).

    Blocks of GEOMETRY_BLOCK leaves (one block with shading, which couples all kept leaves). A
    ValueError names the numbers if the window cannot hold the farthest kept leaf (max delay +
    call length >= N / fs).
    """
    idx, r, th2, s1, nd = kept.index, kept.r, kept.theta2, kept.s1, kept.nd
    v = params.speed
    a0 = params.peak_amplitude
    channels = _ear_geometry(beam, params)
    C = len(channels)
    m = idx.shape[0]
    incident = params.beam_model == "incident_freq"
    doppler = params.doppler and params.moving
    monostatic = not params.ears
    beta = np.empty((C, m))
    beam_gain = np.empty((C, m))
    rest = np.empty((C, m)) if incident else _filled(1.0, C, m)
    tau = np.empty((C, m))
    path = np.empty((C, m)) if params.absorption else _filled(0.0, C, m)
    cap = np.empty((C, m)) if params.near_field_cap else _filled(0.0, C, m)
    theta2 = np.empty((C, 2, m)) if incident else _filled(0.0, C, 2, m)
    leaf_ratio = np.empty((C, m)) if doppler else _filled(1.0, C, m)
    eta = np.empty((C, m)) if doppler else _filled(1.0, C, m)
    a_kept = np.empty(m)
    # offsets (M,3) are read only by shading, the ears and the moving platform
    need_d = params.shading or not monostatic or params.moving
    # shading couples all kept leaves: one block; otherwise blocks of GEOMETRY_BLOCK
    step = max(m, 1) if params.shading else GEOMETRY_BLOCK
    vel = np.asarray(params.platform_velocity, dtype=np.float64)
    pos = beam.position
    for start in range(0, m, step):
        blk = slice(start, min(start + step, m))
        ib = idx[blk]
        rb, th2b, s1b, ndb = r[blk], th2[blk], s1[blk], nd[blk]
        ab = np.maximum(a.take(ib), params.a_min)
        a_kept[blk] = ab
        if need_d:
            d = c.take(ib, axis=0) - pos
            nb = n.take(ib, axis=0)
            nn = np.sqrt(np.einsum("ij,ij->i", nb, nb))
            u = d / rb[:, None]
        shade: F64 | float = 1.0
        if params.shading and rb.shape[0] > 1:
            shade = shading_factor(u, rb, ab, ndb / rb, params.shading_opacity)
        t1 = rb / v
        for ch, (pos_rx, axis_rx, sig) in enumerate(channels):
            if monostatic:
                dr, rr, th2r, s1r = (d if need_d else None), rb, th2b, s1b
                cosb = np.abs(ndb)
                cosb /= rb
                np.clip(cosb, 0.0, 1.0, out=cosb)
                np.arccos(cosb, out=beta[ch, blk])
            else:
                dr = d + (pos - pos_rx)
                rr = np.sqrt(np.einsum("ij,ij->i", dr, dr))
                rr = np.maximum(rr, params.r_min)
                ur = dr / rr[:, None]
                th2r = off_axis_squared(ur, axis_rx, params)
                s1r = a0 * np.exp(-th2r / (2.0 * sig * sig))
                bis = u + ur
                bis_n = np.sqrt(np.einsum("ij,ij->i", bis, bis))
                ok = bis_n > 0.0
                bis = np.where(ok[:, None], bis / np.where(ok, bis_n, 1.0)[:, None], u)
                nhat_bis = np.abs(np.einsum("ij,ij->i", nb, bis)) / nn
                beta[ch, blk] = np.arccos(np.clip(nhat_bis, 0.0, 1.0))
            spread = 1.0 / (rb * rr) if params.spreading else 1.0
            gain = np.multiply(s1b, s1r, out=beam_gain[ch, blk])
            if incident:
                np.multiply(shade, spread, out=rest[ch, blk])
                theta2[ch, 0, blk] = th2b
                theta2[ch, 1, blk] = th2r
            else:
                gain *= np.multiply(shade, spread)
            if params.near_field_cap:
                cap[ch, blk] = 0.5 * np.sqrt(rb * rr)
            if params.absorption:
                path[ch, blk] = rb + rr
            if params.moving and dr is not None:
                q = dr - vel * t1[:, None]
                qq = np.einsum("ij,ij->i", q, q)
                qv = _rowdot(q, vel)
                vv = float(vel @ vel)
                s = qq / (qv + np.sqrt(qv * qv + (v * v - vv) * qq))
                tau[ch, blk] = t1 + s
                if doppler:
                    u_rx = (q - vel * s[:, None]) / (v * s)[:, None]
                    leaf_ratio[ch, blk] = v / (v - _rowdot(u, vel))
                    eta[ch, blk] = leaf_ratio[ch, blk] * (v + _rowdot(u_rx, vel)) / v
            else:
                np.add(rb, rr, out=tau[ch, blk])
                tau[ch, blk] /= v
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
        a=a_kept,
        beta=beta,
        beam=beam_gain,
        rest=rest,
        tau=tau,
        path=path,
        cap=cap,
        theta2=theta2,
        leaf_ratio=leaf_ratio,
        eta=eta,
        dropped=dropped,
        speed=v,
        in_beam=in_beam,
        cut=cut,
    )
