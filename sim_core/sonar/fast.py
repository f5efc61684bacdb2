"""Fast fidelities: Chebyshev-in-frequency expansion + type-1 NUFFT (``fast``), and ``realtime``.

Method (``fast``). The echo spectrum is X_k = w_k sum_i W_i(f_k) exp(-j 2 pi f_k tau_i) with a
per-leaf weight W_i(f) = A_i(f) exp(-j psi_i(f)) that is smooth across the band (it depends on f
only through c = k a, which varies by f_hi/f_lo = 4/3). So W_i is replaced by its polynomial
interpolant at P Chebyshev nodes of the band, W_i(f) ~ sum_p W_i(f_p) l_p(f) (Lagrange basis),
and with x_i = 2 pi (fs/N) tau_i and f_k = (m0 + k) fs/N

    X_k = w_k sum_p l_p(f_k) sum_i [W_i(f_p) e^{-j (m0 + K0) x_i}] e^{-j (k - K0) x_i}

where the inner sums, one per node p, are P type-1 NUFFTs of the delays (finufft, one batched
call, K0 = B // 2 centres the modes). Cost O(P M + P B log B) instead of O(M B) for B band bins.
The weights at the nodes are evaluated in float32 (SIMD transcendentals, error ~1e-6) and the
NUFFT runs in single precision for eps >= 1e-5; the large phase (m0 + K0) x_i is reduced
modulo 2 pi in float64 first. The window w_k, like every leaf-independent factor, multiplies
after the sum. Geometry, guards and selection are shared with ``reference`` (model.prepare).
``realtime`` runs ``fast`` on at most the number of leaves its time budget allows, keeping the
leaves with the largest waterdrop metric S1/r (i.e. it raises the selection threshold G).
"""

from __future__ import annotations

import functools
import math
import threading
from typing import Any

import finufft
import numpy as np
from numpy.typing import NDArray

from sim_core.sonar.model import Scene, leaf_weights
from sim_core.sonar.params import EchoParams
from sim_core.sonar.reference import Band, Fidelity, direct_sum

__all__ = ["Fast", "Realtime", "chebyshev_nodes", "lagrange_basis"]

#: leaves per block of the node evaluation (keeps the temporaries in cache)
BLOCK = 8192
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
#: up to this many kinked leaves per echo are summed directly (exactly)
DIRECT_KINKED = 8
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
    MAX_ORDER) and the group recomputed (``adapt=None``: never). ``error_bound`` reported per
    echo = CHECK_MARGIN x that check error (amplitude-weighted, kinked leaves counted at
    KINK_ERROR when interpolated) + 2 eps + the float32 phase floor. Measured errors against
    ``reference``: docs/sonar.md and BENCHMARKS.md.
    """

    name = "fast"

    def __init__(
        self,
        order: int = 3,
        eps: float = 1e-4,
        kink_order: int = 16,
        adapt: float | None = 2e-4,
    ) -> None:
        for name, value in (("order", order), ("kink_order", kink_order)):
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 64:
                raise ValueError(f"Fast.{name} must be an integer in [1, 64], got {value!r}")
        if not 1e-14 <= eps < 1e-1:
            raise ValueError(f"Fast.eps must be in [1e-14, 0.1), got {eps!r}")
        if adapt is not None and not adapt > 0:
            raise ValueError(f"Fast.adapt must be None or > 0, got {adapt!r}")
        self.order = order
        self.kink_order = kink_order
        self.eps = eps
        self.adapt = adapt

    def supports(self, params: EchoParams) -> str | None:
        if params.doppler and params.moving:
            return "Doppler frequency scaling is implemented by fidelity 'reference' only"
        return None

    def run(self, scene: Scene, params: EchoParams) -> Band:
        g = params.grid
        B = g.count
        C = scene.beta.shape[0]
        if scene.count == 0:
            return Band(np.zeros((C, B), dtype=np.complex128), g.m0, 0.0)
        out = np.empty((C, B), dtype=np.complex128)
        bound = 0.0
        centre_f = 0.5 * (g.m0 + g.m1) * g.df
        for ch in range(C):
            kinked = _kinked(scene, ch, params)
            order = self.order_for(params)
            spec, tail, weight = self._group(scene, ch, params, order, ~kinked)
            while self.adapt is not None and tail > self.adapt and order < MAX_ORDER:
                order = min(2 * order, MAX_ORDER)
                spec, tail, weight = self._group(scene, ch, params, order, ~kinked)
            err = tail * weight
            n_kinked = int(np.count_nonzero(kinked))
            if n_kinked:
                sub = scene.select(np.flatnonzero(kinked))
                if n_kinked <= DIRECT_KINKED:
                    spec += direct_sum(sub, ch, params)
                    weight += float(np.abs(leaf_weights(sub, ch, [centre_f], params)).sum())
                else:
                    spec_k, _, weight_k = self._group(sub, ch, params, self.kink_order, None)
                    spec += spec_k
                    err += KINK_ERROR * weight_k
                    weight += weight_k
            out[ch] = spec
            bound = max(bound, err / weight if weight > 0 else 0.0)
        out *= g.window
        floor = (B // 2) * math.pi * 2.0**-24 + 1e-6 if self.eps >= SINGLE_EPS else 0.0
        return Band(out, g.m0, CHECK_MARGIN * bound + 2.0 * self.eps + floor)

    def _group(
        self,
        scene: Scene,
        ch: int,
        params: EchoParams,
        P: int,
        mask: NDArray[np.bool_] | None,
    ) -> tuple[NDArray[np.complex128], float, float]:
        """Interpolated sum of one group of leaves: (spectrum (B,), tail, amplitude weight)."""
        g = params.grid
        B = g.count
        f_lo, f_hi = g.m0 * g.df, g.m1 * g.df
        centre, half = 0.5 * (f_lo + f_hi), 0.5 * (f_hi - f_lo)
        nodes = chebyshev_nodes(P)
        basis = _basis(P, g.m0, g.m1)
        single = self.eps >= SINGLE_EPS
        cdt = np.complex64 if single else np.complex128
        K0 = B // 2
        M = scene.count
        strengths = np.empty((P, M), dtype=cdt)
        f_nodes = centre + half * nodes
        cycles = g.df * scene.tau[ch]
        shift = (np.mod((g.m0 + K0) * cycles, 1.0) * (2.0 * np.pi)).astype(strengths.real.dtype)
        rot: NDArray[np.complexfloating] = np.empty(M, dtype=cdt)
        rot.real = np.cos(shift)
        rot.imag = -np.sin(shift)
        if mask is not None:
            rot *= mask
        for start in range(0, M, BLOCK):
            blk = slice(start, min(start + BLOCK, M))
            w = leaf_weights(scene.select(blk), ch, f_nodes, params, single=single,
                             freq_major=True)
            np.multiply(w, rot[blk], out=strengths[:, blk])
        x = ((np.mod(cycles + 0.5, 1.0) - 0.5) * (2.0 * np.pi)).astype(strengths.real.dtype)
        if M < LOOP_MIN_LEAVES:
            plan = _plan(B, self.eps, single, P)
            plan.setpts(x)
            modes = plan.execute(strengths)
        else:
            modes = np.empty((P, B), dtype=cdt)
            plan = _plan(B, self.eps, single, 1)
            plan.setpts(x)
            for p in range(P):
                plan.execute(strengths[p], out=modes[p])
        tail, weight = _interpolation_error(scene, ch, params, strengths, rot, nodes, mask)
        return np.einsum("kp,pk->k", basis, modes), tail, weight

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


def _kinked(scene: Scene, ch: int, params: EchoParams) -> NDArray[np.bool_]:
    """Leaves whose weight has a kink inside the band, shape (M,) bool.

    L = max(0, P1 cos(P2 beta)) is clipped where P2(c) beta crosses pi/2 (P2 falls with f), and
    the near-field cap min(g0 L / k, r/2) switches on where g0 P1 / k can reach r/2.
    """
    g = params.grid
    k_lo = 2.0 * np.pi * g.m0 * g.df / scene.speed
    k_hi = 2.0 * np.pi * g.m1 * g.df / scene.speed
    ap = 0.3999 * scene.a**-0.9065
    beta = scene.beta[ch]
    x_lo = (ap * k_lo**-0.9065 + 0.9979) * beta
    x_hi = (ap * k_hi**-0.9065 + 0.9979) * beta
    out: NDArray[np.bool_] = (x_lo > 0.5 * np.pi) & (x_hi < 0.5 * np.pi)
    if params.near_field_cap:
        c_hi = k_hi * scene.a
        out |= params.g0 * (0.5003 * c_hi * c_hi + 0.6867) / k_lo >= scene.cap[ch]
    return out


def _interpolation_error(
    scene: Scene,
    ch: int,
    params: EchoParams,
    strengths: NDArray[np.complexfloating],
    rot: NDArray[np.complexfloating],
    nodes: NDArray[np.float64],
    mask: NDArray[np.bool_] | None,
) -> tuple[float, float]:
    """A-posteriori interpolation error of a group: (relative error, amplitude weight).

    On an even sample of at most CHECK_SAMPLE leaves the interpolant is compared with the exact
    weights at 2P + 1 check frequencies (Chebyshev points interleaved with the nodes):
    error = sum_i max_f |interp - exact| / sum_i max_f |exact|. The weight is that amplitude
    sum rescaled to all leaves of the group. ``strengths`` = W(f_p) * ``rot`` (P, M).
    """
    index = np.flatnonzero(mask) if mask is not None else np.arange(scene.count)
    if index.shape[0] == 0:
        return 0.0, 0.0
    pick = index[:: max(1, index.shape[0] // CHECK_SAMPLE)]
    g = params.grid
    f_lo, f_hi = g.m0 * g.df, g.m1 * g.df
    check = chebyshev_nodes(2 * nodes.shape[0] + 1)
    exact = leaf_weights(
        scene.select(pick), ch, 0.5 * (f_lo + f_hi) + 0.5 * (f_hi - f_lo) * check, params
    )
    w = (strengths[:, pick] / rot[pick]).T
    approx = np.einsum("mp,pc->mc", w, _check_basis(nodes.shape[0]).astype(w.real.dtype))
    amp = np.abs(exact).max(axis=1)
    total = float(amp.sum())
    if total == 0.0:
        return 0.0, 0.0
    err = float(np.abs(approx - exact).max(axis=1).sum())
    return err / total, total * index.shape[0] / pick.shape[0]


_PLANS = threading.local()


def _plan(modes: int, eps: float, single: bool, n_trans: int) -> Any:
    """A per-thread cached finufft type-1 plan for ``n_trans`` transforms (points unsorted: the
    fine grid of a few thousand points fits in cache, so sorting only costs)."""
    cache: dict[tuple[int, float, bool, int], Any] = _PLANS.__dict__.setdefault("plans", {})
    key = (modes, eps, single, n_trans)
    if key not in cache:
        cache[key] = finufft.Plan(
            1, (modes,), n_trans=n_trans, eps=eps, isign=-1, nthreads=1, spread_sort=0,
            dtype="complex64" if single else "complex128",
        )
    return cache[key]


class Realtime(Fidelity):
    """``fast`` within a per-echo time budget (``EchoParams.budget_s``).

    The affordable leaf count is (budget_s - overhead_s) / per_leaf_s (a fixed, deterministic
    cost model measured on the reference machine; same inputs -> same echo). If more leaves are
    in the beam, only that many with the largest S1/r are synthesised: the selection threshold
    G is raised until they fit. The reported ``error_bound`` adds to the ``fast`` bound the
    dropped leaves' share under the random-phase model of a foliage echo (leaves at
    independent ranges add incoherently): ||X_drop|| ~ ||w|| sqrt(sum_i max_f |W_i(f)|^2),
    with max_f |W_i| bounded by g0 P1(k_hi a) S / (k_lo r^2), times DROP_MARGIN, relative to
    the synthesised spectrum. It is a statistical bound, not a worst case (coherent
    alignments of the dropped leaves could exceed it); BENCHMARKS.md compares it with the
    measured error.
    """

    name = "realtime"

    def __init__(
        self,
        order: int = 3,
        eps: float = 1e-3,
        overhead_s: float = 4e-4,
        per_leaf_s: float = 3e-7,
    ) -> None:
        self.fast = Fast(order=order, eps=eps, adapt=None)
        if not (overhead_s >= 0 and per_leaf_s > 0):
            raise ValueError(
                f"Realtime cost model needs overhead_s >= 0 and per_leaf_s > 0, got "
                f"{overhead_s!r}, {per_leaf_s!r}"
            )
        self.overhead_s = overhead_s
        self.per_leaf_s = per_leaf_s

    def supports(self, params: EchoParams) -> str | None:
        return self.fast.supports(params)

    def capacity(self, params: EchoParams) -> int:
        """Leaves affordable per channel within ``params.budget_s``."""
        C = params.channels
        return max(1, int((params.budget_s / C - self.overhead_s) / self.per_leaf_s))

    def run(self, scene: Scene, params: EchoParams) -> Band:
        cap = self.capacity(params)
        if scene.count <= cap:
            band = self.fast.run(scene, params)
            return Band(band.spectra, band.lo_bin, band.error_bound)
        order = np.argpartition(-scene.q, cap - 1)
        kept, dropped = scene.select(np.sort(order[:cap])), scene.select(order[cap:])
        band = self.fast.run(kept, params)
        g = params.grid
        kk_lo = 2.0 * np.pi * g.m0 * g.df / scene.speed
        c_hi = 2.0 * np.pi * g.m1 * g.df / scene.speed * dropped.a
        p1 = 0.5003 * c_hi * c_hi + 0.6867
        bound = 0.0
        w_norm = float(np.linalg.norm(g.window))
        for ch in range(scene.beta.shape[0]):
            amax = params.g0 * p1 / kk_lo * dropped.beam[ch] * dropped.rest[ch]
            if params.beam_model == "incident_freq":
                amax = params.g0 * p1 / kk_lo * params.peak_amplitude**2 * dropped.rest[ch]
            kept_norm = float(np.linalg.norm(band.spectra[ch]))
            drop_norm = DROP_MARGIN * w_norm * float(np.sqrt(np.sum(amax * amax)))
            bound = max(bound, drop_norm / kept_norm if kept_norm > 0 else math.inf)
        return Band(band.spectra, band.lo_bin, (band.error_bound or 0.0) + bound)
