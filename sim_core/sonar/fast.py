"""Fast fidelities: Chebyshev-in-frequency expansion + type-1 NUFFT (``fast``), and ``realtime``.

Method (``fast``). The echo spectrum is X_k = w_k sum_i W_i(f_k) exp(-j 2 pi f_k tau_i) with a
per-leaf weight W_i(f) = A_i(f) exp(-j psi_i(f)) that is smooth across the band (it depends on f
only through c = k a, which varies by f_hi/f_lo = 4/3). So W_i is replaced by its polynomial
interpolant at P Chebyshev nodes of the band, W_i(f) ~ sum_p W_i(f_p) l_p(f) (Lagrange basis),
and with x_i = 2 pi (fs/N) tau_i and f_k = (m0 + k) fs/N

    X_k = w_k sum_p l_p(f_k) sum_i [W_i(f_p) e^{-j (m0 + K0) x_i}] e^{-j (k - K0) x_i}

where the inner sums, one per node p, are P type-1 NUFFTs of the delays (finufft on a cached
plan, K0 = B // 2 centres the modes). Cost O(P M + P B log B) instead of O(M B) for B band bins.
The weights at the nodes are evaluated in float32 (SIMD transcendentals, error ~1e-6) and the
NUFFT runs in single precision for eps >= 1e-5, as do the band spectra it returns (so the
output transform, :func:`~sim_core.sonar.api.assemble`, runs in float32 too); the large phase
(m0 + K0) x_i is reduced modulo 2 pi in float64 first and added to the weight's phase. The
leaves are processed in blocks of BLOCK on workspace arrays (fresh pages cost more than the
arithmetic). The window w_k, like every leaf-independent factor, multiplies after the sum.
Geometry, guards and selection are shared with ``reference`` (model.prepare). ``realtime``
gives ``prepare`` a :class:`~sim_core.sonar.model.LeafBudget` for the whole echo: it tests and
synthesises only the leaves its budget affords, those with the largest waterdrop metric S1/r
(the selection threshold G raised), and bounds the rest.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from numpy.typing import NDArray

from sim_core.sonar.cost import COST
from sim_core.sonar.geometry import Scene
from sim_core.sonar.model import LeafBudget
from sim_core.sonar.params import EchoParams
from sim_core.sonar.reference import Band, Fidelity, direct_sum
from sim_core.sonar.weights import leaf_weights
from sim_core.sonar.workspace import Workspace

__all__ = ["Fast", "Realtime", "chebyshev_nodes", "lagrange_basis"]

#: leaves per block of the node evaluation (keeps the temporaries in cache)
BLOCK = 16384
#: margin on the random-phase estimate of the leaves ``realtime`` drops
DROP_MARGIN = 1.0
#: the largest node count adaptation goes to
MAX_ORDER = 24
#: groups with at least this many leaves run one NUFFT per node on a cached plan (finufft's
#: batched mode is slower there); smaller groups use one batched call
LOOP_MIN_LEAVES = 20_000
#: factor on the sampled interpolation error in ``error_bound`` (the check measures the
#: per-leaf max error on a sample; at P = 2 the echo error reached 1.2x it in BENCHMARKS.md)
CHECK_MARGIN = 2.0
#: leaves sampled (evenly) for the per-echo a-posteriori interpolation error
CHECK_SAMPLE = 128
#: minimum Chebyshev nodes with the frequency-dependent (incident_freq) beamwidth
INCIDENT_FREQ_ORDER = 12
#: NUFFT tolerances at or above this run in single precision (float32 delays: the phase of mode
#: k is off by at most |k| pi 2^-24, i.e. <= 7.2e-5 at the band edges for the default band)
SINGLE_EPS = 1e-5
#: up to this many kinked leaves per echo are summed directly (exactly) when they are summed apart
DIRECT_KINKED = 8
#: kinked leaves are interpolated with the others while their worst-case error stays below this
#: share of the amplitude weight (typical foliage: 2e-4 of 0.7 % of the leaves, all near
#: grazing incidence); above it they are summed apart
KINK_SHARE = 3e-4
#: relative error bound of a kinked leaf interpolated at ``kink_order`` = 16 nodes (worst case
#: measured over the kink range of a = 1 mm .. 0.4 m: 0.34)
KINK_ERROR = 0.5


def chebyshev_nodes(count: int) -> NDArray[np.float64]:
    """Chebyshev points of the first kind on [-1, 1], shape (count,)."""
    p = np.arange(count)
    return np.cos(np.pi * (2 * p + 1) / (2 * count))


def lagrange_basis(nodes: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lagrange basis l_p(t) for ``nodes`` (P,), evaluated at ``t`` (K,) -> (K, P)."""
    P = nodes.shape[0]
    out = np.ones((t.shape[0], P))
    for p in range(P):
        for q in range(P):
            if q != p:
                out[:, p] *= (t - nodes[q]) / (nodes[p] - nodes[q])
    return out


class Fast(Fidelity):
    """Chebyshev interpolation at ``order`` nodes + finufft type-1 at tolerance ``eps``.

    The interpolation error is checked a posteriori on a sample of leaves (exact weights at
    2P + 1 check frequencies); if it exceeds ``adapt`` the node count is doubled (up to
    MAX_ORDER) and the group recomputed (``adapt=None``: never).

    Kinked leaves (the clip of L or the near-field cap inside the band, see :func:`_kinked`)
    are interpolated with the others while their worst case, (1 + Lambda_P) sum_i max_f |W_i|
    (Lambda_P the Lebesgue constant of P Chebyshev nodes), stays below ``kink_share`` of the
    amplitude weight; otherwise up to DIRECT_KINKED are summed directly and more are
    interpolated apart at ``kink_order`` nodes and counted at KINK_ERROR of their weight.
    ``error_bound`` reported per echo = (CHECK_MARGIN x check error + the kinked leaves'
    share) + 2 eps + the float32 phase floor. Measured errors against ``reference``:
    docs/sonar.md and BENCHMARKS.md.
    """

    name = "fast"

    def __init__(
        self,
        order: int = 3,
        eps: float = 1e-4,
        kink_order: int = 16,
        adapt: float | None = 2e-4,
        kink_share: float = KINK_SHARE,
    ) -> None:
        for name, value in (("order", order), ("kink_order", kink_order)):
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 64:
                raise ValueError(f"Fast.{name} must be an integer in [1, 64], got {value!r}")
        if not 1e-14 <= eps < 1e-1:
            raise ValueError(f"Fast.eps must be in [1e-14, 0.1), got {eps!r}")
        if adapt is not None and not adapt > 0:
            raise ValueError(f"Fast.adapt must be None or > 0, got {adapt!r}")
        if not kink_share > 0:
            raise ValueError(f"Fast.kink_share must be > 0, got {kink_share!r}")
        self.order = order
        self.kink_order = kink_order
        self.eps = eps
        self.adapt = adapt
        self.kink_share = kink_share

    def supports(self, params: EchoParams) -> str | None:
        if params.doppler and params.moving:
            return "Doppler frequency scaling is implemented by fidelity 'reference' only"
        return None

    def run(self, scene: Scene, params: EchoParams, workspace: Workspace) -> Band:
        g = params.grid
        B = g.count
        C = scene.beta.shape[0]
        # single precision end to end: the spectra, and so the output transform (assemble)
        cdt = np.complex64 if self.eps >= SINGLE_EPS else np.complex128
        if scene.count == 0:
            return Band(np.zeros((C, B), dtype=cdt), g.m0, 0.0)
        out = np.empty((C, B), dtype=cdt)
        bound = 0.0
        centre_f = 0.5 * (g.m0 + g.m1) * g.df
        for ch in range(C):
            kinked, amax = _kinked(scene, ch, params)
            order = self.order_for(params)
            n_kinked = kinked.shape[0]
            apart = False
            spec, tail, weight = self._group(scene, ch, params, order, kinked, apart, workspace)
            while self.adapt is not None and tail > self.adapt and order < MAX_ORDER:
                order = min(2 * order, MAX_ORDER)
                spec, tail, weight = self._group(scene, ch, params, order, kinked, apart, workspace)
            # interpolating f -> max(0, f) at P Chebyshev nodes errs by at most (1 + Lambda_P)
            # max|f|, Lambda_P <= 1 + (2/pi) ln P (Lebesgue constant)
            kink_err = (2.0 + 2.0 / math.pi * math.log(order)) * float(amax.sum())
            if not apart and kink_err > self.kink_share * weight:
                apart = True
                spec, tail, weight = self._group(scene, ch, params, order, kinked, apart, workspace)
            err = CHECK_MARGIN * tail * weight
            if n_kinked and apart:
                kink_err = 0.0
                sub = scene.select(kinked)
                if n_kinked <= DIRECT_KINKED:
                    spec += direct_sum(sub, ch, params, workspace)
                    w = leaf_weights(sub, ch, [centre_f], params, workspace=workspace)
                    weight += float(np.abs(w).sum())
                else:
                    none = np.empty(0, dtype=np.intp)
                    spec_k, _, weight_k = self._group(sub, ch, params, self.kink_order, none,
                                                      False, workspace)
                    spec += spec_k
                    err += CHECK_MARGIN * KINK_ERROR * weight_k
                    weight += weight_k
            out[ch] = spec
            if weight > 0:
                bound = max(bound, (err + kink_err) / weight)
            elif err + kink_err > 0:
                bound = math.inf
        out *= g.window
        floor = (B // 2) * math.pi * 2.0**-24 + 1e-6 if self.eps >= SINGLE_EPS else 0.0
        return Band(out, g.m0, bound + 2.0 * self.eps + floor)

    def _group(
        self,
        scene: Scene,
        ch: int,
        params: EchoParams,
        P: int,
        kinked: NDArray[np.intp],
        apart: bool,
        ws: Workspace,
    ) -> tuple[NDArray[np.complex128], float, float]:
        """Interpolated sum of the leaves: (spectrum (B,), tail, amplitude weight).

        The ``kinked`` leaves are left out of the error check, and (``apart``) out of the sum.
        """
        g = params.grid
        B = g.count
        f_lo, f_hi = g.m0 * g.df, g.m1 * g.df
        centre, half = 0.5 * (f_lo + f_hi), 0.5 * (f_hi - f_lo)
        nodes = chebyshev_nodes(P)
        basis = _basis(P, g.m0, g.m1)
        single = self.eps >= SINGLE_EPS
        cdt = np.complex64 if single else np.complex128
        rdt = np.float32 if single else np.float64
        K0 = B // 2
        M = scene.count
        strengths = ws.array("strengths", (P, M), cdt)
        x = ws.array("x", (M,), rdt)
        f_nodes = centre + half * nodes
        for start in range(0, M, BLOCK):
            blk = slice(start, min(start + BLOCK, M))
            cycles = g.df * scene.tau[ch, blk]
            # x = 2 pi (cycles mod 1, centred) and the phase (m0 + K0) x, reduced in float64
            frac = cycles + 0.5
            frac -= np.floor(frac)
            frac -= 0.5
            frac *= 2.0 * np.pi
            x[blk] = frac
            cycles *= g.m0 + K0
            cycles -= np.floor(cycles)
            cycles *= 2.0 * np.pi
            leaf_weights(scene.select(blk), ch, f_nodes, params, single=single, freq_major=True,
                         phase=cycles, out=strengths[:, blk], workspace=ws)
        if apart and kinked.shape[0]:
            strengths[:, kinked] = 0.0
        if M < LOOP_MIN_LEAVES:
            plan = ws.plan(B, self.eps, single, P)
            plan.setpts(x)
            modes = plan.execute(strengths)
        else:
            modes = np.empty((P, B), dtype=cdt)
            plan = ws.plan(B, self.eps, single, 1)
            plan.setpts(x)
            for p in range(P):
                plan.execute(strengths[p], out=modes[p])
        tail, weight = _interpolation_error(scene, ch, params, nodes, kinked, ws, single=single)
        return np.einsum("kp,pk->k", basis.astype(rdt, copy=False), modes), tail, weight

    def order_for(self, params: EchoParams) -> int:
        """Nodes used for ``params``: at least INCIDENT_FREQ_ORDER with the BW(f) beam."""
        if params.beam_model == "incident_freq":
            return max(self.order, INCIDENT_FREQ_ORDER)
        return self.order


@functools.lru_cache(maxsize=64)
def _check_basis(P: int) -> NDArray[np.float64]:
    """Lagrange basis of P Chebyshev nodes at the 2P + 1 check points, (P, 2P + 1)."""
    return lagrange_basis(chebyshev_nodes(P), chebyshev_nodes(2 * P + 1)).T


@functools.lru_cache(maxsize=64)
def _basis(P: int, m0: int, m1: int) -> NDArray[np.float64]:
    """Lagrange basis of P Chebyshev nodes over the band bins m0..m1, (m1 - m0 + 1, P)."""
    k = np.arange(m0, m1 + 1, dtype=np.float64)
    return lagrange_basis(chebyshev_nodes(P), (k - 0.5 * (m0 + m1)) / (0.5 * (m1 - m0)))


def _kinked(
    scene: Scene, ch: int, params: EchoParams
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Leaves whose weight has a kink inside the band: (indices (K,), max_f |W_i| bounds (K,)).

    L = max(0, P1 cos(P2 beta)) is clipped where P2(c) beta crosses pi/2 (P2 falls with f), and
    the near-field cap min(g0 L / k, r/2) switches on where g0 P1 / k can reach r/2. Since
    P2 >= 0.9979, only beta in (pi/2 / P2(k_lo min a), pi/2 / 0.9979) can be clipped; those are
    examined. The bound: P1 and cos(P2 beta) grow with f across the band (P2 beta < pi), 1/k
    falls, absorption only reduces: max_f |W| <= g0 P1(k_hi a) max(cos(P2(k_hi a) beta), 0) /
    k_lo x gain (or the cap r/2 x gain).
    """
    g = params.grid
    k_lo = 2.0 * np.pi * g.m0 * g.df / scene.speed
    k_hi = 2.0 * np.pi * g.m1 * g.df / scene.speed
    beta = scene.beta[ch]
    if params.near_field_cap:
        cand = np.arange(scene.count)
    else:
        p2_max = 0.3999 * (k_lo * float(scene.a.min())) ** -0.9065 + 0.9979
        cand = np.flatnonzero((beta > 0.5 * np.pi / p2_max) & (beta < 0.5 * np.pi / 0.9979))
    a, beta = scene.a[cand], beta[cand]
    ap = 0.3999 * a**-0.9065
    x_lo = (ap * k_lo**-0.9065 + 0.9979) * beta
    x_hi = (ap * k_hi**-0.9065 + 0.9979) * beta
    hit = (x_lo > 0.5 * np.pi) & (x_hi < 0.5 * np.pi)
    c_hi = k_hi * a
    amax = params.g0 * (0.5003 * c_hi * c_hi + 0.6867) * np.maximum(np.cos(x_hi), 0.0) / k_lo
    if params.near_field_cap:
        cap = scene.cap[ch][cand]
        hit |= params.g0 * (0.5003 * c_hi * c_hi + 0.6867) / k_lo >= cap
        amax = np.minimum(amax, cap)
    if params.beam_model == "incident_freq":
        amax *= params.peak_amplitude**2 * scene.rest[ch][cand]
    else:
        amax *= scene.beam[ch][cand]
    return cand[hit], amax[hit]


def _interpolation_error(
    scene: Scene,
    ch: int,
    params: EchoParams,
    nodes: NDArray[np.float64],
    skip: NDArray[np.intp],
    ws: Workspace,
    *,
    single: bool,
) -> tuple[float, float]:
    """A-posteriori interpolation error of a group: (relative error, amplitude weight).

    On an even sample of at most CHECK_SAMPLE leaves the interpolant is compared with the exact
    weights at 2P + 1 check frequencies (Chebyshev points interleaved with the nodes), evaluated
    in the synthesis's precision (``single``: float32, whose ~1e-6 rounding the error then
    includes, as the synthesis does):
    error = sum_i max_f |interp - exact| / sum_i max_f |exact|. The weight is that amplitude
    sum rescaled to all leaves of the group. Leaves ``skip`` (sorted) are not sampled.
    """
    count = scene.count - skip.shape[0]
    if count <= 0:
        return 0.0, 0.0
    pick = np.arange(0, scene.count, max(1, count // CHECK_SAMPLE))
    if skip.shape[0]:
        at = np.minimum(np.searchsorted(skip, pick), skip.shape[0] - 1)
        pick = pick[skip[at] != pick]
    if pick.shape[0] == 0:
        pick = np.delete(np.arange(scene.count), skip)[:CHECK_SAMPLE]
    g = params.grid
    f_lo, f_hi = g.m0 * g.df, g.m1 * g.df
    centre, half = 0.5 * (f_lo + f_hi), 0.5 * (f_hi - f_lo)
    check = chebyshev_nodes(2 * nodes.shape[0] + 1)
    both = leaf_weights(scene.select(pick), ch, centre + half * np.concatenate([check, nodes]),
                        params, single=single, workspace=ws)
    exact, w = both[:, : check.shape[0]], both[:, check.shape[0] :]
    approx = np.einsum("mp,pc->mc", w, _check_basis(nodes.shape[0]).astype(w.real.dtype))
    amp = np.abs(exact).max(axis=1)
    total = float(amp.sum())
    if total == 0.0:
        return 0.0, 0.0
    err = float(np.abs(approx - exact).max(axis=1).sum())
    return err / total, total * count / pick.shape[0]


class Realtime(Fidelity):
    """``fast`` within a per-echo time budget (``EchoParams.budget_s``), geometry included.

    A fixed, deterministic cost model (:class:`~sim_core.sonar.model.LeafBudget`, by default
    the constants of :data:`sim_core.sonar.cost.COST`, the model the server's echo deadlines
    plan with; same inputs -> same echo): an echo costs ``overhead_s`` +
    ``per_examined_s`` per leaf examined by the range / cone pre-cull + ``per_candidate_s`` per
    leaf passing it + ``per_selected_s`` per candidate given the off-axis angle and waterdrop
    test + ``per_leaf_s`` per leaf synthesised (incidence, gain, delay, node weights, NUFFT).
    What the budget cannot afford is left out: the farthest candidates untested, then the
    selected leaves with the smallest waterdrop metric S1/r (the selection threshold G is
    raised); their incidence and weights are never computed.

    ``error_bound`` = the ``fast`` bound + the share of the left-out leaves under the
    random-phase model of a foliage echo (leaves at independent ranges add incoherently):
    ||X_cut|| ~ ||w|| sqrt(sum_i max_f |W_i(f)|^2) with max_f |W_i| <= g0 P1(k_hi a) S /
    (k_lo r^2) (S <= A0^2 for untested leaves), times DROP_MARGIN, relative to the synthesised
    spectrum (1 if nothing could be synthesised: a zero echo). It is a statistical bound, not a
    worst case (coherent alignments of the left-out leaves could exceed it); the tests check it
    on random scenes and BENCHMARKS.md compares it with the measured error.
    """

    name = "realtime"

    def __init__(
        self,
        order: int = 3,
        eps: float = 1e-3,
        overhead_s: float = COST.overhead_s,
        per_leaf_s: float = COST.per_leaf_s,
        per_examined_s: float = COST.per_examined_s,
        per_selected_s: float = COST.per_selected_s,
        per_candidate_s: float = COST.per_candidate_s,
    ) -> None:
        self.fast = Fast(order=order, eps=eps, adapt=None, kink_share=math.inf)
        costs = (overhead_s, per_examined_s, per_selected_s, per_candidate_s)
        if not (all(math.isfinite(x) and x >= 0 for x in costs) and per_leaf_s > 0):
            raise ValueError(
                "Realtime cost model needs overhead_s, per_examined_s, per_selected_s, "
                f"per_candidate_s >= 0 and per_leaf_s > 0, got {overhead_s!r}, "
                f"{per_examined_s!r}, {per_selected_s!r}, {per_candidate_s!r}, {per_leaf_s!r}"
            )
        self.overhead_s = overhead_s
        self.per_leaf_s = per_leaf_s
        self.per_examined_s = per_examined_s
        self.per_selected_s = per_selected_s
        self.per_candidate_s = per_candidate_s

    def supports(self, params: EchoParams) -> str | None:
        return self.fast.supports(params)

    def leaf_budget(self, params: EchoParams) -> LeafBudget:
        return LeafBudget(
            budget_s=params.budget_s,
            overhead_s=self.overhead_s,
            per_examined_s=self.per_examined_s,
            per_candidate_s=self.per_candidate_s,
            per_selected_s=self.per_selected_s,
            per_leaf_s=self.per_leaf_s,
        )

    def capacity(self, params: EchoParams, examined: int = 0, candidates: int = 0) -> int:
        """Leaves synthesised per channel after testing all ``candidates`` of ``examined``."""
        budget = self.leaf_budget(params)
        per_channel = dataclasses.replace(budget, budget_s=budget.budget_s / params.channels)
        return per_channel.synthesised(examined, candidates, candidates)

    def run(self, scene: Scene, params: EchoParams, workspace: Workspace) -> Band:
        g = params.grid
        band = self.fast.run(scene, params, workspace)
        cut = scene.cut
        if cut.count == 0:
            return band
        w_norm = float(np.linalg.norm(g.window))
        bound = 0.0
        for ch in range(scene.beta.shape[0]):
            kept_norm = float(np.linalg.norm(band.spectra[ch]))
            drop_norm = DROP_MARGIN * w_norm * float(cut.amax[ch])
            if kept_norm > 0:
                bound = max(bound, drop_norm / kept_norm)
            else:
                bound = max(bound, 1.0 if scene.count == 0 else math.inf)
        return Band(band.spectra, band.lo_bin, (band.error_bound or 0.0) + bound)
