"""The foliage echo model of ``docs/spec/echo_model.md``, up to the kept leaves: guards and beam
selection.

:func:`prepare` is shared by every fidelity: it applies the guards (leaves with a non-finite
centre, normal or radius, a zero normal or r < r_min are dropped and counted), culls by range
and cone, applies the waterdrop test r <= r0 S1 and, under a :class:`LeafBudget`, keeps only
what the budget affords (:func:`_cut_amax` bounds the rest); the per-leaf terms of the kept
leaves are then computed by :func:`sim_core.sonar.geometry.leaf_terms` into the
:class:`~sim_core.sonar.geometry.Scene` the fidelities sum. :func:`precull_half_angle` gives
the cone of the pre-cull to the cost model (:mod:`sim_core.sonar.cost`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.sonar.geometry import Cut, Kept, Scene, leaf_terms, off_axis_squared
from sim_core.sonar.params import Beam, EchoParams
from sim_core.sonar.precull import precull
from sim_core.sonar.workspace import Workspace

__all__ = [
    "INDEX_MAX_SHARE",
    "INDEX_MIN_LEAVES",
    "LeafBudget",
    "LeafSource",
    "precull_half_angle",
    "prepare",
]

F64 = NDArray[np.float64]


@runtime_checkable
class LeafSource(Protocol):
    """Anything with leaf arrays: ``centers`` (M,3) m, ``normals`` (M,3), ``radii`` (M,) m."""

    @property
    def centers(self) -> ArrayLike: ...

    @property
    def normals(self) -> ArrayLike: ...

    @property
    def radii(self) -> ArrayLike: ...


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

    def cull(self, c: F64, n: F64, a: F64, rows: NDArray[np.intp] | None, ws: Workspace,
             ) -> tuple[int, int, NDArray[np.intp], F64, F64, F64, F64]:
        """The compiled pre-cull (:func:`sim_core.sonar.precull.precull`: guards, range and
        cone) of the leaves (``rows`` of them, if given): (survivors, dropped by the guards,
        and the survivors' rows, r, r . b, offsets (K, 3), n_hat . d), in ``ws`` scratch."""
        total = c.shape[0] if rows is None else rows.shape[0]
        out = (ws.array("cull_rows", total, np.intp), ws.array("cull_r", total, np.float64),
               ws.array("cull_proj", total, np.float64),
               ws.array("cull_d", 3 * total, np.float64).reshape(total, 3),
               ws.array("cull_nd", total, np.float64))
        found, dropped = precull(c, n, a, rows, self.pos, self.axis, r_min2=self.r_min2,
                                 reach2=self.reach2, cone=self.cone, cos_reach=self.cos_reach,
                                 out=out)
        rows_k, r, proj, d, nd = (x[:found] for x in out)
        return found, dropped, rows_k, r, proj, d, nd


def _nearest(
    c: F64, n: F64, a: F64, sel: _Selection, budget: LeafBudget, params: EchoParams,
    ws: Workspace,
) -> tuple[NDArray[np.intp], int, int, Cut]:
    """Rows of the nearest leaves passing the pre-cull that ``budget`` affords to test (ties
    kept), the number dropped by the guards, the number that passed, and the farther ones left
    untested (their bound takes the beam gain at its peak A0)."""
    total = c.shape[0]
    found, dropped, rows, ranges = sel.cull(c, n, a, None, ws)[:4]
    rows, ranges = rows.copy(), ranges.copy()  # the selection's own cull reuses the scratch
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
    ws: Workspace,
    budget: LeafBudget | None = None,
) -> tuple[Kept, int, int, int, Cut]:
    """Guards and waterdrop selection: (kept, dropped, candidates, tested, untested).

    ``kept`` holds the kept rows of ``c`` with their r, theta^2 (the spec's off-axis angle, or
    the seed2020 az/el form), S1 and n_hat.d (the unit normal dotted with the offset, m). Every
    leaf first passes the guards and a range and cone pre-cull without
    transcendentals (:meth:`_Selection.cull`, compiled); the waterdrop test r <= r0 S1 is taken on
    logarithms, and with the spec's exact expression where both sides are within
    _SELECTION_SLACK. With a ``budget`` that cannot afford every candidate (pre-cull survivor),
    only the nearest it affords are tested (:func:`_nearest`; ``untested`` the others). The
    arrays are ``ws`` scratch, valid until its next selection.
    """
    sel = _Selection.of(beam, params)
    rows_in: NDArray[np.intp] | None = None
    dropped = 0
    total = c.shape[0]
    untested = Cut(0, np.zeros(params.channels))
    found = -1
    if budget is not None and total > budget.candidates(total):
        rows_in, dropped, found, untested = _nearest(c, n, a, sel, budget, params, ws)
        total = rows_in.shape[0]
    r0, a0, sigma = sel.r0, sel.a0, sel.sigma
    inv2s2 = 1.0 / (2.0 * sigma * sigma)
    log_scale = 1.0 / (r0 * a0)
    tested, gone, rows, r, proj, d, nd = sel.cull(c, n, a, rows_in, ws)
    dropped += gone
    with np.errstate(invalid="ignore", divide="ignore"):
        if params.seed2020:
            th2 = off_axis_squared(d, sel.axis, params)
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
    if not keep.all():
        rows, r, th2 = rows.compress(keep), r.compress(keep), th2.compress(keep)
        nd = nd.compress(keep)
    s1 = th2 * -inv2s2
    s1 = _exp(s1)
    s1 *= a0
    found = tested if found < 0 else found
    return Kept(rows, r, th2, s1, nd), dropped, found, tested, untested


def _strongest(
    kept: Kept, a: F64, cut: Cut, wanted: int, params: EchoParams
) -> tuple[Kept, Cut]:
    """The ``wanted`` kept leaves with the largest waterdrop metric S1/r (in row order) and
    ``cut`` grown by the others (``a``: the radii of the rows ``kept`` indexes)."""
    selected = kept.count
    if wanted >= selected:
        return kept, cut
    wanted = max(wanted, 0)
    if wanted:
        metric = np.divide(kept.s1, kept.r)
        np.negative(metric, out=metric)
        order = np.argpartition(metric, wanted - 1)
    else:
        order = np.arange(selected)
    out = order[wanted:]
    amax = _cut_amax(params, kept.r[out], a.take(kept.index[out]), kept.s1[out])
    cut = Cut(cut.count + selected - wanted, np.hypot(cut.amax, amax))
    return kept.select(np.sort(order[:wanted])), cut


def prepare(
    leaves: LeafSource | tuple[ArrayLike, ArrayLike, ArrayLike],
    beam: Beam,
    params: EchoParams,
    *,
    budget: LeafBudget | None = None,
    workspace: Workspace | None = None,
) -> Scene:
    """Apply the guards and the beam selection; compute per-leaf quantities (spec, all channels).

    Guards: leaves with a non-finite centre/normal/radius, a zero normal or r < r_min are dropped
    and counted; if the window cannot hold the farthest kept leaf (max delay + call length >=
    N / fs) a ValueError names the numbers. For INDEX_MIN_LEAVES or more leaves with a
    ``query_ball(point, r)`` method (``sim_core.world.Leaves``) only that ball is examined.

    The selection (:func:`_select`, its pre-cull one compiled pass over the leaves),
    then incidence, gain and delay for the kept leaves only
    (:func:`~sim_core.sonar.geometry.leaf_terms`). With a ``budget`` (:class:`LeafBudget`) the
    waterdrop test sees only the nearest candidates it affords, and of the selected leaves only
    as many as it affords are kept, those with the largest waterdrop metric S1/r (raising the
    threshold G); ``Scene.cut`` summarises the others. Scratch arrays come from ``workspace``
    (a new :class:`~sim_core.sonar.workspace.Workspace` if None); the Scene never aliases them.
    """
    ws = Workspace() if workspace is None else workspace
    c, n, a = _leaf_arrays(leaves)
    a0 = params.peak_amplitude
    cand = _candidates(leaves, c.shape[0], beam, params.selection_radius * max(a0, 1.0))
    if cand is not None:
        c, n, a = c.take(cand, axis=0), n.take(cand, axis=0), a.take(cand)
    examined = c.shape[0]
    per_channel = None
    if budget is not None:
        per_channel = dataclasses.replace(budget, budget_s=budget.budget_s / params.channels)
    kept, dropped, found, tested, cut = _select(c, n, a, beam, params, ws, per_channel)
    in_beam = kept.count + cut.count
    if per_channel is not None:
        wanted = per_channel.synthesised(examined, found, tested)
        kept, cut = _strongest(kept, a, cut, wanted, params)
    return leaf_terms(c, n, a, kept, beam, params, dropped=dropped, in_beam=in_beam, cut=cut)


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
