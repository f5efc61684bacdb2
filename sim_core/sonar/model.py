"""The foliage echo model of ``docs/spec/echo_model.md``: guards, beam selection, per-leaf terms.

Shared by every fidelity: :func:`prepare` applies the guards and the beam selection and returns
the per-leaf, frequency-independent quantities (:class:`Scene`); :func:`leaf_weights` evaluates
the per-leaf, per-frequency complex weight W_ik (everything except the delay phase and the
leaf-independent window); :func:`assemble` turns band spectra into time samples. Fidelities
differ only in how they evaluate sum_i W_ik exp(-j 2 pi f_k tau_i).
"""

from __future__ import annotations

import dataclasses
import math
import threading
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
from sim_core.sonar.seedbeam import off_axis

__all__ = [
    "Cut",
    "LeafBudget",
    "LeafSource",
    "Scene",
    "assemble",
    "leaf_weights",
    "precull_half_angle",
    "prepare",
    "window_at",
]

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
    two-way beam gain S = S1(emitter) S1(ear) times ``rest``, the shading / spreading factor,
    except with ``beam_model="incident_freq"`` (S then depends on f): there ``beam`` is S at
    the fixed beamwidth and ``rest`` (C,M) that factor, otherwise ``rest`` is all ones;
    ``tau`` (C,M) two-way delay s; ``path`` (C,M) two-way path length m; ``cap`` (C,M)
    near-field cap r/2 m; ``theta2`` (C,2,M) squared off-axis angles of emitter and ear (for
    ``incident_freq``); ``leaf_ratio`` (C,M) leaf-frame / emitted frequency and ``eta`` (C,M)
    received / emitted frequency (both 1 without Doppler). ``dropped``: leaves removed by the
    guards; ``in_beam``: leaves
    the beam selects (the kept leaves plus ``cut``, those a :class:`LeafBudget` left out; under
    a range cut the untested candidates are counted, so it is then an upper bound).
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


def _theta2(u: F64, axis: F64, params: EchoParams) -> F64:
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


#: leaf sets at least this large are culled through their own ``query_ball`` (a k-d tree that
#: pays for its construction only when a large set is reused across pings); smaller sets, such
#: as the per-ping ``TiledForest.leaves_near`` result, are culled by the vectorised cone test
INDEX_MIN_LEAVES = 200_000
#: above this share of the leaves inside the ball the index is not used (see _candidates)
INDEX_MAX_SHARE = 0.25


def _candidates(
    leaves: object, count: int, beam: Beam, reach: float
) -> NDArray[np.intp] | None:
    """Indices within ``reach`` of the sonar from the leaves' own spatial index, if worth it.

    With a ``kdtree`` (cKDTree, e.g. ``sim_core.world.Leaves``) the ball is counted first
    (cheap): if it holds more than INDEX_MAX_SHARE of the leaves, listing it would cost more
    than the vectorised pre-cull of all of them, which then runs instead.
    """
    query = getattr(leaves, "query_ball", None)
    if query is None or count < INDEX_MIN_LEAVES:
        return None
    tree = getattr(leaves, "kdtree", None)
    if tree is not None:
        inside = int(tree.query_ball_point(beam.position, reach, return_length=True))
        if inside > INDEX_MAX_SHARE * count:
            return None
    return np.asarray(query(beam.position, reach), dtype=np.intp)


#: leaves whose selection test lies this close to the boundary are decided with the spec's
#: exact formula (the fast test uses a logarithm instead of the exponential)
_SELECTION_SLACK = 1e-9
#: ``_exp`` refines a float32 exponential in float64 only for arguments down to this value
#: (the refined error is below 1e-14 there); smaller ones use the float64 exponential
_EXP_REFINE_MIN = -30.0


def _exp(x: F64) -> F64:
    """exp(x) for x <= 0, float64, relative error < 1e-14 (float32 SIMD exp, refined).

    numpy's float64 exp is scalar libm on machines without AVX-512 (~7 ns per value); the
    float32 one is vectorised. y0 = exp32(x) = exp(x - e) with e = x - log(y0) <~ 2e-6 (the
    float32 rounding of x and of the result), so exp(x) = y0 (1 + e + e^2/2) up to e^3/6.
    """
    if x.shape[0] == 0 or float(x.min()) < _EXP_REFINE_MIN:
        return np.exp(x)
    y0 = np.exp(x.astype(np.float32)).astype(np.float64)
    e = x - np.log(y0)
    corr = e * 0.5
    corr += 1.0
    corr *= e
    corr += 1.0
    corr *= y0
    return corr


@dataclass(frozen=True, slots=True)
class Cut:
    """Selected leaves left out of the synthesis by a :class:`LeafBudget` (``realtime``).

    ``count`` leaves; ``amax`` (C,) = sqrt(sum_i max_f |W_i(f)|^2) over them per channel, with
    max_f |W_i| bounded by g0 P1(k_hi a_i) S_i / (k_lo r_i r_ear,i) (the random-phase norm of
    their spectrum before the window, see :class:`sim_core.sonar.fast.Realtime`).
    """

    count: int
    amax: F64


_WORKSPACE = threading.local()
#: scratch arrays larger than this are allocated per call instead of kept per thread (bounds
#: the memory a thread holds between pings; at this size the page faults are a small share)
SCRATCH_MAX_BYTES = 32 << 20


def _workspace(name: str, size: int, dtype: type) -> NDArray[Any]:
    """A per-thread scratch array of ``size`` elements, reused between pings (up to
    SCRATCH_MAX_BYTES).

    For results that do not outlive the call that asks for them (fresh pages for large arrays
    are slow; reused ones are not).
    """
    if size * np.dtype(dtype).itemsize > SCRATCH_MAX_BYTES:
        return np.empty(size, dtype=dtype)
    cache: dict[str, NDArray[Any]] = _WORKSPACE.__dict__.setdefault("arrays", {})
    buf = cache.get(name)
    if buf is None or buf.shape[0] < size or buf.dtype != dtype:
        buf = np.empty(max(size, 1024), dtype=dtype)
        cache[name] = buf
    return buf[:size]


#: leaves per block of the geometry pass: temporaries of 128 KiB stay in cache and in the
#: allocator's free lists (whole-array temporaries of 1e5 leaves are fresh pages each time,
#: which cost more than the arithmetic on them)
GEOMETRY_BLOCK = 16384


@dataclass(frozen=True, slots=True)
class LeafBudget:
    """A per-echo time budget and the cost model ``prepare`` plans the geometry with (s).

    An echo costs ``overhead_s`` + ``per_examined_s`` per leaf examined by the guards and the
    range / cone pre-cull + ``per_candidate_s`` per leaf passing it (bookkeeping, or the bound
    of one left untested) + ``per_selected_s`` per candidate given the off-axis angle and
    waterdrop test + ``per_leaf_s`` per leaf synthesised. If the candidates exceed what the
    rest of the budget affords, only the nearest are tested (the range cut-off r0 is lowered,
    i.e. the threshold G raised); if more are selected than can be synthesised, those with the
    largest S1/r are kept (``Scene.cut`` summarises the others).
    """

    budget_s: float
    overhead_s: float
    per_examined_s: float
    per_candidate_s: float
    per_selected_s: float
    per_leaf_s: float

    def _left(self, examined: int, found: int, tested: int) -> float:
        return (
            self.budget_s
            - self.overhead_s
            - self.per_examined_s * examined
            - self.per_candidate_s * found
            - self.per_selected_s * tested
        )

    def candidates(self, examined: int) -> int:
        """Candidates affordable even if all were tested and synthesised (no range cut needed
        when ``examined`` is at most this)."""
        unit = self.per_candidate_s + self.per_selected_s + self.per_leaf_s
        return max(0, int(self._left(examined, 0, 0) / unit))

    def tested(self, examined: int, found: int) -> int:
        """Candidates the waterdrop test may see when ``found`` of ``examined`` passed."""
        return max(0, int(self._left(examined, found, 0) / (self.per_selected_s + self.per_leaf_s)))

    def synthesised(self, examined: int, found: int, tested: int) -> int:
        """Leaves that can be synthesised after testing ``tested`` of ``found`` candidates."""
        return max(0, int(self._left(examined, found, tested) / self.per_leaf_s))


def precull_half_angle(beam: Beam, params: EchoParams) -> float:
    """Half-angle (rad) of the cone outside which the pre-cull rejects every leaf of ``beam``
    (no kept leaf is further off axis); pi when the pre-cull has no cone."""
    sel = _Selection.of(beam, params)
    return math.acos(min(1.0, sel.cos_reach + 1e-12)) if sel.cone else math.pi


@dataclass(frozen=True, slots=True)
class _Selection:
    """Constants of the beam selection of one ping (see :func:`_select`)."""

    pos: F64
    axis: F64
    r0: float
    a0: float
    sigma: float
    cone: bool
    cos_reach: float
    reach2: float
    r_min2: float

    @staticmethod
    def of(beam: Beam, params: EchoParams) -> _Selection:
        r0 = params.selection_radius
        a0 = params.peak_amplitude
        sigma = beam.sigma
        # S1 >= r/r0 >= r_min/r0 bounds the off-axis angle of any kept leaf
        reach = sigma * math.sqrt(2.0 * math.log(max(a0 * r0 / params.r_min, 1.0 + 1e-12)))
        return _Selection(
            pos=beam.position,
            axis=beam.boresight,
            r0=r0,
            a0=a0,
            sigma=sigma,
            cone=not params.seed2020 and reach < math.pi,
            cos_reach=math.cos(reach) - 1e-12,
            reach2=(r0 * a0) ** 2,
            r_min2=params.r_min**2,
        )

    def precull(
        self, cb: F64, nb: F64, ab: F64
    ) -> tuple[NDArray[np.bool_], int, F64, F64, F64, F64, F64, F64]:
        """Guards, range and cone on a block (no transcendental): (candidates, dropped by the
        guards, r, r . b, dx, dy, dz, |n|^2)."""
        pos, axis = self.pos, self.axis
        dx, dy, dz = cb[:, 0] - pos[0], cb[:, 1] - pos[1], cb[:, 2] - pos[2]
        nx, ny, nz = nb[:, 0], nb[:, 1], nb[:, 2]
        with np.errstate(invalid="ignore", over="ignore"):
            r2 = dx * dx
            r2 += dy * dy
            r2 += dz * dz
            nn2 = nx * nx
            nn2 += ny * ny
            nn2 += nz * nz
            valid = nn2 > 0.0
            valid &= r2 >= self.r_min2
            if not math.isfinite(float(r2.sum()) + float(nn2.sum()) + float(ab.sum())):
                valid &= np.isfinite(dx + dy + dz + (nx + ny + nz) + ab)
            dropped = ab.shape[0] - int(np.count_nonzero(valid))
            valid &= r2 <= self.reach2
            r = np.sqrt(r2, out=r2)
            proj = dx * axis[0]
            proj += dy * axis[1]
            proj += dz * axis[2]
            if self.cone:
                valid &= proj >= self.cos_reach * r
        return valid, dropped, r, proj, dx, dy, dz, nn2


def _nearest(
    c: F64, n: F64, a: F64, sel: _Selection, budget: LeafBudget, params: EchoParams
) -> tuple[NDArray[np.intp], int, int, Cut]:
    """Rows of the nearest leaves passing the pre-cull that ``budget`` affords to test (ties
    kept), the number dropped by the guards, the number that passed, and the farther ones left
    untested (their bound takes the beam gain at its peak A0)."""
    total = c.shape[0]
    rows = _workspace("near_rows", total, np.intp)
    ranges = _workspace("near_r", total, np.float64)
    found = 0
    dropped = 0
    for start in range(0, total, GEOMETRY_BLOCK):
        stop = min(start + GEOMETRY_BLOCK, total)
        valid, gone, r = sel.precull(c[start:stop], n[start:stop], a[start:stop])[:3]
        dropped += gone
        hit = np.flatnonzero(valid)
        rows[found : found + hit.shape[0]] = hit + start
        ranges[found : found + hit.shape[0]] = r.compress(valid)
        found += hit.shape[0]
    rows, ranges = rows[:found], ranges[:found]
    untested = Cut(0, np.zeros(params.channels))
    count = budget.tested(total, found)
    if found > count:
        keep = ranges <= np.partition(ranges, count - 1)[count - 1] if count else ranges < 0.0
        far = ~keep
        r_far = ranges.compress(far)
        peak = np.full(r_far.shape[0], sel.a0)
        amax = _cut_amax(params, r_far, a.take(rows.compress(far)), peak)
        untested = Cut(r_far.shape[0], amax)
        rows = rows.compress(keep)
    return rows, dropped, found, untested


def _select(
    c: F64,
    n: F64,
    a: F64,
    beam: Beam,
    params: EchoParams,
    budget: LeafBudget | None = None,
) -> tuple[NDArray[np.intp], F64, F64, F64, F64, int, int, int, Cut]:
    """Guards and waterdrop selection: (index, r, theta^2, S1, n_hat.d, dropped, candidates,
    tested, untested).

    ``index`` (K,) are the kept rows of ``c``; r, theta^2 (the spec's off-axis angle, or the
    seed2020 az/el form), S1 and n_hat.d (the unit normal dotted with the offset, m) are
    theirs. Every leaf first passes the guards and a range and cone pre-cull without
    transcendentals (:meth:`_Selection.precull`); the waterdrop test r <= r0 S1 is taken on
    logarithms, and with the spec's exact expression where both sides are within
    _SELECTION_SLACK. With a ``budget`` that cannot afford every candidate (pre-cull survivor),
    only the nearest it affords are tested (:func:`_nearest`; ``untested`` the others). The
    arrays are per-thread scratch, valid until the next call.
    """
    sel = _Selection.of(beam, params)
    rows_in: NDArray[np.intp] | None = None
    dropped = 0
    total = c.shape[0]
    untested = Cut(0, np.zeros(params.channels))
    found = -1
    if budget is not None and total > budget.candidates(total):
        rows_in, dropped, found, untested = _nearest(c, n, a, sel, budget, params)
        total = rows_in.shape[0]
    tested = 0
    r0, a0, sigma = sel.r0, sel.a0, sel.sigma
    inv2s2 = 1.0 / (2.0 * sigma * sigma)
    log_scale = 1.0 / (r0 * a0)
    index = _workspace("index", total, np.intp)
    outs = [_workspace(name, total, np.float64) for name in ("r", "th2", "s1", "nd")]
    kept = 0
    for start in range(0, total, GEOMETRY_BLOCK):
        stop = min(start + GEOMETRY_BLOCK, total)
        if rows_in is None:
            cb, nb, ab = c[start:stop], n[start:stop], a[start:stop]
        else:
            rb = rows_in[start:stop]
            cb, nb, ab = c.take(rb, axis=0), n.take(rb, axis=0), a.take(rb)
        valid, gone, r, proj, dx, dy, dz, nn = sel.precull(cb, nb, ab)
        dropped += gone
        with np.errstate(invalid="ignore", divide="ignore"):
            nd = nb[:, 0] * dx
            nd += nb[:, 1] * dy
            nd += nb[:, 2] * dz
            nd /= np.sqrt(nn, out=nn)
        everyone = bool(valid.all())
        if not everyone:
            if not valid.any():
                continue
            r, proj, nd = r.compress(valid), proj.compress(valid), nd.compress(valid)
        tested += r.shape[0]
        if params.seed2020:
            d = np.stack([dx, dy, dz], 1)
            th2 = _theta2(d if everyone else d.compress(valid, axis=0), sel.axis, params)
        else:
            proj /= r
            np.clip(proj, -1.0, 1.0, out=proj)
            th2 = np.arccos(proj, out=proj)
            th2 *= th2
        test = np.log(r * log_scale)
        test += th2 * inv2s2
        keep = test <= 0.0
        near = np.abs(test) < _SELECTION_SLACK
        if near.any():
            at = np.flatnonzero(near)
            keep[at] = r[at] <= r0 * (a0 * np.exp(-th2[at] / (2.0 * sigma * sigma)))
        rows = np.arange(start, stop) if everyone else np.flatnonzero(valid) + start
        if not keep.all():
            rows, r, th2 = rows.compress(keep), r.compress(keep), th2.compress(keep)
            nd = nd.compress(keep)
        k = rows.shape[0]
        index[kept : kept + k] = rows if rows_in is None else rows_in.take(rows)
        outs[0][kept : kept + k] = r
        outs[1][kept : kept + k] = th2
        th2 *= -inv2s2
        outs[2][kept : kept + k] = _exp(th2)
        outs[3][kept : kept + k] = nd
        kept += k
    r, th2, s1, nd = (x[:kept] for x in outs)
    s1 *= a0
    return index[:kept], r, th2, s1, nd, dropped, tested if found < 0 else found, tested, untested


def prepare(
    leaves: LeafSource | tuple[ArrayLike, ArrayLike, ArrayLike],
    beam: Beam,
    params: EchoParams,
    *,
    budget: LeafBudget | None = None,
) -> Scene:
    """Apply the guards and the beam selection; compute per-leaf quantities (spec, all channels).

    Guards: leaves with a non-finite centre/normal/radius, a zero normal or r < r_min are dropped
    and counted; if the window cannot hold the farthest kept leaf (max delay + call length >=
    N / fs) a ValueError names the numbers. For INDEX_MIN_LEAVES or more leaves with a
    ``query_ball(point, r)`` method (``sim_core.world.Leaves``) only that ball is examined.

    Blocks of GEOMETRY_BLOCK leaves over coordinate columns: the selection (:func:`_select`),
    then incidence, gain and delay for the kept leaves only. With a ``budget``
    (:class:`LeafBudget`) the waterdrop test sees only the nearest candidates it affords, and
    of the selected leaves only as many as it affords are kept, those with the largest
    waterdrop metric S1/r (raising the threshold G); ``Scene.cut`` summarises the others.
    """
    c, n, a = _leaf_arrays(leaves)
    v = params.speed
    a0 = params.peak_amplitude
    cand = _candidates(leaves, c.shape[0], beam, params.selection_radius * max(a0, 1.0))
    if cand is not None:
        c, n, a = c.take(cand, axis=0), n.take(cand, axis=0), a.take(cand)
    examined = c.shape[0]
    per_channel = None
    if budget is not None:
        per_channel = dataclasses.replace(budget, budget_s=budget.budget_s / params.channels)
    idx, r, th2, s1, nd, dropped, found, tested, cut = _select(c, n, a, beam, params, per_channel)
    selected = int(idx.shape[0])
    in_beam = selected + cut.count
    channels = _ear_geometry(beam, params)
    C = len(channels)
    wanted = selected
    if per_channel is not None:
        wanted = per_channel.synthesised(examined, found, tested)
    if wanted < selected:
        wanted = max(wanted, 0)
        if wanted:
            metric = np.divide(s1, r)
            np.negative(metric, out=metric)
            order = np.argpartition(metric, wanted - 1)
        else:
            order = np.arange(selected)
        out = order[wanted:]
        amax = _cut_amax(params, r[out], a.take(idx[out]), s1[out])
        cut = Cut(cut.count + selected - wanted, np.hypot(cut.amax, amax))
        sel = np.sort(order[:wanted])
        idx, r, th2, s1, nd = idx[sel], r[sel], th2[sel], s1[sel], nd[sel]
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
                th2r = _theta2(ur, axis_rx, params)
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


def _cut_amax(params: EchoParams, r: F64, a: F64, s1: F64) -> F64:
    """Per channel sqrt(sum_i max_f |W_i(f)|^2) of leaves left out by a budget, (C,).

    max_f |W_i| <= g0 P1(k_hi a) S / (k_lo r r_ear): L <= P1 (increasing in f), 1/k <= 1/k_lo,
    absorption, shading and the near-field cap only reduce it; an ear's own gain is bounded by
    A0 (and the frequency-dependent beam by A0^2), its range by r - |ear offset| (>= r_min).
    """
    g = params.grid
    v = params.speed
    k_lo = 2.0 * np.pi * g.m0 * g.df / v
    k_hi = 2.0 * np.pi * g.m1 * g.df / v
    a0 = params.peak_amplitude
    p1 = np.maximum(a, params.a_min)
    p1 *= k_hi
    p1 *= p1
    p1 *= 0.5003
    p1 += 0.6867
    p1 *= params.g0 / k_lo
    out = np.empty(params.channels)
    for ch in range(params.channels):
        w = p1.copy()
        if params.beam_model == "incident_freq":
            w *= a0 * a0
        else:
            w *= s1
            w *= a0 if params.ears else s1
        if params.spreading:
            w /= r
            if params.ears:
                off = float(np.linalg.norm(params.ears[ch].offset))
                w /= np.maximum(r - off, params.r_min)
            else:
                w /= r
        w *= w
        out[ch] = math.sqrt(float(w.sum()))
    return out


def _filled(value: float, *shape: int) -> F64:
    """A read-only broadcast array of ``value`` (no memory per leaf) for unused fields."""
    return np.broadcast_to(np.float64(value), shape)


def _scratch(name: str, shape: tuple[int, ...], dtype: Any) -> NDArray[Any]:
    """A per-thread scratch array of ``shape`` (see :func:`_workspace`), one per name and dtype."""
    dt = np.dtype(dtype)
    return _workspace(f"{name}:{dt.char}", math.prod(shape), dt.type).reshape(shape)


def _erf_fast(x: NDArray[np.floating]) -> NDArray[np.floating]:
    """erf via Abramowitz & Stegun 7.1.26 (|error| <= 1.5e-7), SIMD-friendly for float32.

    Overwrites and returns ``x``.
    """
    dt = x.dtype.type
    ax = np.abs(x, out=_scratch("erf_ax", x.shape, dt))
    t = np.multiply(ax, dt(0.3275911), out=_scratch("erf_t", x.shape, dt))
    t += dt(1.0)
    np.reciprocal(t, out=t)
    poly = np.multiply(t, dt(1.061405429), out=_scratch("erf_poly", x.shape, dt))
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
) -> NDArray[np.complexfloating]:
    """Per-leaf, per-frequency weight W = A exp(-j psi) (no delay phase, no window), (M, F).

    ``f_leaf`` Hz is the frequency the leaf sees, shape (F,) or (M, F). A = g0 S L / k / r^2
    (spec), with the opt-in absorption, near-field cap and incident-frequency beam applied.
    ``single=True`` evaluates in float32 with a 1.5e-7 erf approximation (fast fidelities;
    relative error ~1e-6), returning complex64. ``freq_major=True`` (``f_leaf`` of shape (F,)
    only) returns the transpose, (F, M). ``phase`` (M,) rad, if given, multiplies leaf i by
    exp(-j phase_i); ``out`` receives the result (a complex array of the result's shape).
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
    beta: Any = leaf(scene.beta[ch].astype(dt))
    shape = np.broadcast_shapes(kk.shape, a64.shape)
    c = np.multiply(kk, a64.astype(dt), out=_scratch("c", shape, dt))
    p1 = np.multiply(dt(0.5003), c, out=_scratch("p1", shape, dt))
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
    lb = np.multiply(ap, (kk64**-0.9065).astype(dt), out=_scratch("lb", shape, dt))
    lb += dt(0.9979)
    lb *= beta
    np.cos(lb, out=lb)
    lb *= p1
    np.maximum(lb, dt(0.0), out=lb)
    psi = np.multiply(bp, (kk64**0.3523).astype(dt), out=_scratch("psi", shape, dt))
    psi -= dt(0.9459)
    psi *= dt(1.57) - beta
    if single:
        _erf_fast(psi)
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
    trig = np.cos(psi, out=_scratch("trig", shape, dt))
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
