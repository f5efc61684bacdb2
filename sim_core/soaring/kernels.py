"""Compiled kernels of seed 002's soaring model: the one implementation of its physics, and of
the continuous flight model's right-hand side and RK4 sub-steps (:mod:`sim_core.flight`, which
uses the seed's polar ``sink``).

Everything that flies is here, compiled by numba (``cache=True``: machine code is written next
to this file, or under ``NUMBA_CACHE_DIR``, and reused by later processes, so the compile cost
is paid once per installation and CPU). The public functions of :mod:`~sim_core.soaring.glider`,
:mod:`~sim_core.soaring.thermals`, :mod:`~sim_core.soaring.boids` and
:class:`~sim_core.soaring.swarm.SwarmSim` are thin wrappers that shape arrays and call these.
All kernels live in this one module because numba invalidates a cached function only when its
own file changes, not when a function it calls does.

Per glider, a step is a scalar loop over float64 with the seed's operations in the seed's order
(``docs/spec/seed_models.md`` §3), each evaluated as GNU Octave evaluates the seed's MATLAB:
``norm`` of a vector is Octave's scaled 2-norm (:func:`norm2`), a scalar ``x^p`` is libm's
``pow`` and an elementwise ``.^`` follows Octave's special cases (:func:`epow`), ``./`` divides,
``dot`` is the fused multiply-add of the reference run's BLAS; exp, cos, sin, tan, atan and acos
are libm's. No fast-math, no reordered sums; sums over neighbours and gliders run in index order.
So a run's result does not depend on the batch it is stepped in, one machine gives the same bits
every time, and the seed's own Octave run (``tests/data/seed002_matlab``) is reproduced to the
last bit where this machine's libm is the one it used.

Layouts (B runs, N glider slots, T thermal slots, K list slots):

* glider state ``S`` (STATE_ROWS, B, N), rows ``ROW_*``; ``alive`` (B, N);
* thermals ``th`` (TH_ROWS, B, T), rows ``TH_*``; ``th_on`` (2, B, T): valid, fades;
* per-run parameters ``par`` (B, len(PAR)), columns named by :data:`PAR` (``P_*``);
* neighbour lists ``nb`` (B, N, K) glider indices, nearest first, ``cnt`` (B, N) used slots;
* metric accumulators ``accf`` (3, B) (``ACC_*``) and ``acci`` (4, B) (``CNT_*``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: Rows of the glider state block. VX, VY (v cos ψ, v sin ψ) are derived at the start of a
#: step; VX..VZ are the rows a neighbour is read from.
ROW_VX, ROW_VY, ROW_X, ROW_Y, ROW_Z, ROW_VZ, ROW_HEADING, ROW_OMEGA, ROW_SPEED, ROW_BANK = range(10)
STATE_ROWS = 10

#: Rows of the thermal block: centre m, radius m, strength m/s, plateau top m/s, direction ±1,
#: plateau timer (steps or s).
TH_X, TH_Y, TH_R, TH_W, TH_WMAX, TH_DIR, TH_TIMER = range(7)
TH_ROWS = 7
ON_VALID, ON_FADE = 0, 1

ACC_FLIGHT, ACC_HEIGHT, ACC_THERMAL = range(3)
CNT_AGENTS, CNT_LIVING, CNT_COLL, CNT_GROUND = range(4)

#: Columns of the per-run parameter table: the law's names, then derived values.
PAR: tuple[str, ...] = (
    "g", "cohesion", "heightFactorPower", "cohesionAscensionIgnore", "cohesionAscensionMax",
    "ascensionFactorPower", "cohPower", "separation", "separationHeightWidth", "sepPower",
    "alignment", "alignmentHeightWidth", "aliPower", "migration", "migPower", "waggle",
    "thermalBankFactor", "neighborRadius", "forwardSpeedMin", "forwardSpeedMax", "bankMin",
    "bankMax", "Sink_A", "Sink_B", "Sink_C", "collisionKillDistance", "agentCeiling",
    "agentFloor", "k", "unified", "target_x", "target_y", "bank_rate_max", "speed_rate_max",
    "fov_limited", "half_fov", "fade_rate", "fade_incr", "fade_top", "fade_bottom",
    "map_min", "map_cell",
)
(P_G, P_KC, P_HFP, P_ASC_IGN, P_ASC_MAX, P_AFP, P_COH_P, P_KS, P_SEP_W, P_SEP_P, P_KA, P_ALI_W,
 P_ALI_P, P_KM, P_MIG_P, P_KW, P_TBF, P_RADIUS, P_V_MIN, P_V_MAX, P_B_MIN, P_B_MAX, P_SINK_A,
 P_SINK_B, P_SINK_C, P_KILL, P_CEIL, P_FLOOR, P_K, P_UNIFIED, P_TX, P_TY, P_BANK_RATE,
 P_SPEED_RATE, P_FOV_LIMITED, P_HALF_FOV, P_FADE_RATE, P_FADE_INCR, P_FADE_TOP, P_FADE_BOTTOM,
 P_MAP_MIN, P_MAP_CELL) = range(len(PAR))

#: Cap of a neighbour's distance weight (d/R)^p, reached only as d → 0 with p < 0.
W_MAX = 1e100
#: Acceleration components beyond ±A_MAX (m/s², or infinite, or NaN → 0) are clipped to it, so
#: ‖a‖² cannot overflow (never hit in the seed's runs, whose |a| stays below 1e6).
A_MAX = 1e100

#: In ``thermalFadeMode: seconds`` a plateau ends when its timer (a sum of dt) reaches the
#: plateau length less this many seconds, so rounding in the sum cannot add a step.
FADE_TOLERANCE = 1e-9

_jit = njit(cache=True, error_model="numpy")


# -- scalar helpers (numpy's NaN rules for minimum, maximum, clip and sign; Octave's arithmetic) --
def _fma(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.fma(*args)

    return types.float64(types.float64, types.float64, types.float64), codegen


def _spow(typingctx: Any, x: Any, y: Any) -> Any:
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        dbl = ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(dbl, [dbl, dbl]),
                                            "pow")
        fn.attributes.add("nobuiltin")
        return builder.call(fn, args)

    return types.float64(types.float64, types.float64), codegen


#: fma(a, b, c) = a·b + c with one rounding (llvm.fma: the CPU's instruction, or libm's fma).
fma: Any = intrinsic(_fma)
#: spow(x, y): libm ``pow`` as called, never rewritten by the optimiser (which turns
#: pow(x, 2.0) into x·x; glibc's pow rounds that differently about once in a thousand):
#: Octave's scalar ``x^y``.
spow: Any = intrinsic(_spow)


@_jit
def epow(x: float, e: float, count: int) -> float:
    """Element of Octave's ``v.^e`` for a vector v of ``count`` elements: a 1-element v is a
    scalar (``pow``); otherwise integer e = 2, 3, −1 are products or 1/x, the rest ``pow``."""
    if count != 1:
        if e == 2.0:
            return x * x
        if e == 3.0:
            return x * x * x
        if e == -1.0:
            return 1.0 / x
    return spow(x, e)


@_jit
def _accum(scl: float, ssq: float, v: float) -> tuple[float, float]:
    t = abs(v)
    if scl == t:
        ssq += 1.0
    elif scl < t:
        r = scl / t
        ssq *= r * r
        ssq += 1.0
        scl = t
    elif t != 0.0:
        r = t / scl
        ssq += r * r
    return scl, ssq


@_jit
def norm2(a: float, b: float) -> float:
    """Octave's ``norm([a b])``: the scaled sum of squares, scl·sqrt(ssq)."""
    scl, ssq = _accum(0.0, 1.0, a)
    scl, ssq = _accum(scl, ssq, b)
    return scl * math.sqrt(ssq)


@_jit
def norm3(a: float, b: float, c: float) -> float:
    """Octave's ``norm([a b c])``."""
    scl, ssq = _accum(0.0, 1.0, a)
    scl, ssq = _accum(scl, ssq, b)
    scl, ssq = _accum(scl, ssq, c)
    return scl * math.sqrt(ssq)


@_jit
def _round(x: float) -> float:
    """C ``round``: halves away from zero."""
    r = np.floor(abs(x))
    if abs(x) - r >= 0.5:
        r += 1.0
    return -r if x < 0.0 else r


@_jit
def _lower(a: float, b: float) -> float:
    return a if (a <= b or a != a) else b


@_jit
def _upper(a: float, b: float) -> float:
    return a if (a >= b or a != a) else b


@_jit
def _sign(a: float) -> float:
    if a > 0.0:
        return 1.0
    if a < 0.0:
        return -1.0
    return 0.0 if a == 0.0 else a


# -- glider (spec §3.3) --------------------------------------------------------------------------
@_jit
def sink(v: float, bank: float, a: float, b: float, c: float) -> float:
    """Polar sink, m/s (< 0 = sinking): (A v² + B v + C) / sqrt(cos φ)."""
    return (a * spow(v, 2.0) + b * v + c) / math.sqrt(math.cos(bank))


@_jit
def command(ax: float, ay: float, c: float, s: float, speed: float, dt: float, g: float,
            tbf: float, w: float) -> tuple[float, float]:
    """Desired planar acceleration → (airspeed_cmd m/s, bank_cmd rad), unclipped."""
    norm = norm2(ax, ay)
    if not norm <= A_MAX:
        ax = 0.0 if ax != ax else min(max(ax, -A_MAX), A_MAX)
        ay = 0.0 if ay != ay else min(max(ay, -A_MAX), A_MAX)
        norm = norm2(ax, ay)
    a_f = fma(ay, s, ax * c)
    a_c = math.sqrt(_upper(spow(norm, 2.0) - spow(a_f, 2.0), 0.0))
    if norm - abs(a_f) < 1e-6:
        a_c = 0.0
    a_c = a_c * _sign(ay * c - ax * s)
    v_cmd = a_f * dt / 10.0 + speed
    bank = math.atan(a_c / g)
    return v_cmd, tbf * w * _sign(bank) + bank


@_jit
def _slew(cmd: float, old: float, rate: float, dt: float) -> float:
    lim = rate * dt
    if math.isinf(lim):
        return cmd
    d = cmd - old
    if d == d:
        d = d if d > -lim else -lim
        d = d if d < lim else lim
    return old + d


@_jit
def fly(x: float, y: float, z: float, heading: float, bank: float, speed: float, v_cmd: float,
        b_cmd: float, w: float, c: float, s: float, dt: float, p: np.ndarray
        ) -> tuple[float, float, float, float, float, float, float, float, bool]:
    """One glider step of dt s from the commands (rate limits, then speed/bank limits), with
    (c, s) = (cos ψ, sin ψ) of the old heading. Returns (x, y, z, heading, omega, speed, bank,
    vz, ground); ``ground``: the new z reached the floor at z <= 0 (the seed's ground death)."""
    v_cmd = _slew(v_cmd, speed, p[P_SPEED_RATE], dt)
    b_cmd = _slew(b_cmd, bank, p[P_BANK_RATE], dt)
    v_max, v_min, b_max, b_min = p[P_V_MAX], p[P_V_MIN], p[P_B_MAX], p[P_B_MIN]
    nv = v_max if v_cmd > v_max else (v_min if v_cmd < v_min else v_cmd)
    nb = b_max if b_cmd > b_max else (b_min if b_cmd < b_min else b_cmd)
    omega = math.tan(nb) * p[P_G] / nv
    vz = sink(nv, nb, p[P_SINK_A], p[P_SINK_B], p[P_SINK_C]) + w
    nx = x + nv * c * dt
    ny = y + nv * s * dt
    nz = z + vz * dt
    floor = p[P_FLOOR]
    below = nz < floor
    ground = below and nz <= 0.0
    nz = p[P_CEIL] if nz > p[P_CEIL] else (floor if below else nz)
    return nx, ny, nz, heading + omega * dt, omega, nv, nb, vz, ground


# -- thermals (spec §3.2) ------------------------------------------------------------------------
@_jit
def updraft(x: float, y: float, th: np.ndarray, on: np.ndarray, b: int) -> float:
    """w m/s at (x, y) of run b: the first thermal in slot order whose disc holds the point."""
    for t in range(th.shape[2]):
        if not on[ON_VALID, b, t]:
            continue
        d = norm2(th[TH_X, b, t] - x, th[TH_Y, b, t] - y)
        r = th[TH_R, b, t]
        if d < r:
            u = spow(3.0 * d / r, 2.0)
            return th[TH_W, b, t] * math.exp(-u) * (1.0 - u)
    return 0.0


@_jit
def fade(th: np.ndarray, on: np.ndarray, b: int, p: np.ndarray) -> None:
    """One step of the fade cycle of run b's fading thermals, in place (``fadeThermals``)."""
    rate, incr = p[P_FADE_RATE], p[P_FADE_INCR]
    for t in range(th.shape[2]):
        if not (on[ON_VALID, b, t] and on[ON_FADE, b, t]):
            continue
        w = th[TH_W, b, t]
        at_top = w >= th[TH_WMAX, b, t] - 1e-5
        if at_top or _round(10.0 * w) / 10.0 <= 1e-5:  # round(w, 1), as the Octave run did
            if th[TH_TIMER, b, t] >= (p[P_FADE_TOP] if at_top else p[P_FADE_BOTTOM]):
                th[TH_DIR, b, t] = -1.0 if at_top else 1.0
                th[TH_W, b, t] = w + th[TH_DIR, b, t] * rate
                th[TH_TIMER, b, t] = 0.0
            else:
                th[TH_TIMER, b, t] = th[TH_TIMER, b, t] + incr
        else:
            th[TH_W, b, t] = w + th[TH_DIR, b, t] * rate


# -- Boids (spec §3.4, §3.6) ---------------------------------------------------------------------
@_jit
def accel(G: np.ndarray, ids: np.ndarray, n: int, own: np.ndarray, heading: float,
          wsign: float, p: np.ndarray) -> tuple[float, float, bool, float]:
    """The Boids controller of one glider (``agentControl_Unified``/``_Baseline``).

    G (6, M): neighbour rows VX, VY, X, Y, Z, VZ; the neighbours are columns ids[:n], in list
    order; own (6,) the glider's own values of those rows, ``heading`` its saved heading (for
    the waggle). Returns (ax, ay) m/s², collision (a neighbour closer than
    collisionKillDistance) and ‖K_c·c‖. A neighbour straight above or below (dxy = 0) adds no
    cohesion, separation or alignment (the seed's NaN); a distance weight (d/R)^p is capped at
    W_MAX; a target at distance 0 adds no migration.
    """
    R, ign = p[P_RADIUS], p[P_ASC_IGN]
    wmax, unified = p[P_ASC_MAX], p[P_UNIFIED] != 0.0
    half_a, half_s = p[P_ALI_W] / 2, p[P_SEP_W] / 2
    n_a = n_s = n  # elements of the vectors Octave raises to a power (1: a scalar pow)
    if unified:
        n_a = n_s = 0
        for q in range(n):
            rz = abs(G[ROW_Z, ids[q]] - own[ROW_Z])
            if rz < half_a:
                n_a += 1
            if rz < half_s:
                n_s += 1
    height = spow(_upper(1.0 - own[ROW_Z] / p[P_CEIL], 0.0), p[P_HFP])
    cx = cy = sx = sy = lx = ly = 0.0
    collision = False
    for q in range(n):
        j = ids[q]
        dx = G[ROW_X, j] - own[ROW_X]
        dy = G[ROW_Y, j] - own[ROW_Y]
        dz = G[ROW_Z, j] - own[ROW_Z]
        dxy2 = dx * dx + dy * dy
        dxy = math.sqrt(dxy2)
        d3 = math.sqrt(dxy2 + dz * dz)
        if d3 < p[P_KILL]:
            collision = True
        if not dxy > 0.0:
            continue
        ex, ey = dx / dxy, dy / dxy
        if unified:
            dwc = _upper(_lower(G[ROW_VZ, j] - own[ROW_VZ], wmax), ign)
            weight = height * epow((dwc - ign) / (wmax - ign), p[P_AFP], n)
            ex_c, ey_c = weight * ex, weight * ey
        else:
            ex_c, ey_c = ex, ey
        w = _lower(epow(dxy / R, p[P_COH_P], n), W_MAX)
        cx += ex_c * w
        cy += ey_c * w
        rz = abs(dz)
        if rz < half_s or not unified:
            w = _lower(epow(d3 / R, p[P_SEP_P], n_s), W_MAX)
            sx += -ex * w
            sy += -ey * w
        if rz < half_a or not unified:
            w = _lower(epow(dxy / R, p[P_ALI_P], n_a), W_MAX)
            lx += (G[ROW_VX, j] - own[ROW_VX]) * w
            ly += (G[ROW_VY, j] - own[ROW_VY]) * w
    nn = float(max(n, 1))  # 1 without neighbours, where every sum is +0.0
    tx, ty = p[P_TX] - own[ROW_X], p[P_TY] - own[ROW_Y]
    dist = norm2(tx, ty)
    mig = spow(dist, p[P_MIG_P]) if dist > 0.0 else 0.0
    kcx, kcy = cx / nn * p[P_KC], cy / nn * p[P_KC]
    ks, ka, km = p[P_KS], p[P_KA], p[P_KM]
    ax = sx / nn * ks + kcx + lx / nn * ka + tx * mig * km
    ay = sy / nn * ks + kcy + ly / nn * ka + ty * mig * km
    kw = p[P_KW]
    if kw != 0.0:  # side unit (cos(ψ + π/2), sin(ψ + π/2)) times the waggle sign
        ax += math.cos(heading + math.pi / 2) * wsign * kw
        ay += math.sin(heading + math.pi / 2) * wsign * kw
    return ax, ay, collision, norm2(kcx, kcy)


@_jit
def find_lists(S: np.ndarray, alive: np.ndarray, cs: np.ndarray, b: int, p: np.ndarray,
               nb: np.ndarray, cnt: np.ndarray, owners_alive: bool) -> None:
    """KNN within radius and field of view of every glider of run b
    (``findNeighborhood_KNNInFixedRadius``), into nb[b] and cnt[b].

    Candidates of i: alive j ≠ i with |Δx| <= R, |Δy| <= R, d3 = norm(Δ) <= R and, if
    fov < 2π, acos((Δx cos ψ_i + Δy sin ψ_i)/d3) <= fov/2 (d3 = 0 gives NaN and is kept, as
    the seed's NaN comparison does; beyond ±1 the cosine gives Octave's real part, π or 0);
    the nearest min(k, K) by d3, ties in index order. cs (2, B, N) holds (cos ψ, sin ψ). With
    ``owners_alive`` a dead glider gets an empty list.
    """
    n, K = alive.shape[1], nb.shape[2]
    R = p[P_RADIUS]
    k = min(int(p[P_K]), K)
    limited, half_fov = p[P_FOV_LIMITED] != 0.0, p[P_HALF_FOV]
    keys = np.empty(K)
    for i in range(n):
        c = 0
        if k > 0 and (alive[b, i] or not owners_alive):
            xi, yi, zi = S[ROW_X, b, i], S[ROW_Y, b, i], S[ROW_Z, b, i]
            for j in range(n):
                if j == i or not alive[b, j]:
                    continue
                dx, dy, dz = S[ROW_X, b, j] - xi, S[ROW_Y, b, j] - yi, S[ROW_Z, b, j] - zi
                if not (abs(dx) <= R and abs(dy) <= R):
                    continue
                d3 = norm3(dx, dy, dz)
                if not d3 <= R:
                    continue
                if limited:
                    cb = (dx * cs[0, b, i] + dy * cs[1, b, i]) / d3
                    angle = math.pi if cb < -1.0 else (0.0 if cb > 1.0 else math.acos(cb))
                    if angle > half_fov:
                        continue
                pos = c  # after every kept key <= d3: stable for ties
                while pos > 0 and keys[pos - 1] > d3:
                    pos -= 1
                if pos >= k:
                    continue
                last = min(c, k - 1)
                for m in range(last, pos, -1):
                    keys[m] = keys[m - 1]
                    nb[b, i, m] = nb[b, i, m - 1]
                keys[pos] = d3
                nb[b, i, pos] = j
                c = min(c + 1, k)
        cnt[b, i] = c


# -- the swarm step (spec §3.1) ------------------------------------------------------------------
@_jit
def headings(S: np.ndarray, cs: np.ndarray, b: int) -> None:
    """cs[:, b] = (cos ψ, sin ψ) and the VX, VY rows of run b from heading and speed."""
    for i in range(S.shape[2]):
        c, s = math.cos(S[ROW_HEADING, b, i]), math.sin(S[ROW_HEADING, b, i])
        cs[0, b, i], cs[1, b, i] = c, s
        S[ROW_VX, b, i] = S[ROW_SPEED, b, i] * c
        S[ROW_VY, b, i] = S[ROW_SPEED, b, i] * s


@_jit
def _step_run(b: int, step: int, dt: float, mfs: int, res: int, S: np.ndarray,
              alive: np.ndarray, nb: np.ndarray, cnt: np.ndarray, th: np.ndarray,
              on: np.ndarray, p: np.ndarray, ext_on: np.ndarray, ext_cmd: np.ndarray,
              wag: np.ndarray, accf: np.ndarray, acci: np.ndarray, visited: np.ndarray,
              zs: np.ndarray, coh: np.ndarray, sc: np.ndarray) -> None:
    """Controller, flight, deaths and metrics of run b for one step, after the thermals faded,
    :func:`headings` and the list refresh. Every glider reads the saved (pre-step) state."""
    n = S.shape[2]
    G = S[:, b, :]
    for i in range(n):  # every glider: the cohesion of a dead one is recorded too
        ax, ay, hit, cm = accel(G, nb[b, i], cnt[b, i], G[:, i], S[ROW_HEADING, b, i],
                                wag[b, i], p)
        coh[b, i] = cm
        sc[2, b, i] = 1.0 if hit else 0.0
        sc[3, b, i], sc[4, b, i] = ax, ay
    living = climbing = 0
    h = accf[ACC_HEIGHT, b]
    explore = step == 1 or step % mfs == 0
    for i in range(n):
        zs[b, i] = S[ROW_Z, b, i]
        if not alive[b, i]:
            h += 0.0
            continue
        if sc[2, b, i] != 0.0:  # collision: dies without moving
            alive[b, i] = False
            acci[CNT_COLL, b] += 1
            h += 0.0
            continue
        x, y, z = S[ROW_X, b, i], S[ROW_Y, b, i], S[ROW_Z, b, i]
        c, s = sc[0, b, i], sc[1, b, i]
        w = updraft(x, y, th, on, b)
        if ext_on[b, i]:
            v_cmd, b_cmd = ext_cmd[0, b, i], ext_cmd[1, b, i]
        else:
            v_cmd, b_cmd = command(sc[3, b, i], sc[4, b, i], c, s, S[ROW_SPEED, b, i], dt,
                                   p[P_G], p[P_TBF], w)
        nx, ny, nz, nh, om, nv, nbank, vz, ground = fly(
            x, y, z, S[ROW_HEADING, b, i], S[ROW_BANK, b, i], S[ROW_SPEED, b, i], v_cmd,
            b_cmd, w, c, s, dt, p)
        S[ROW_BANK, b, i] = nbank
        if ground:  # dies where it was; only the bank was set (as in the seed)
            alive[b, i] = False
            acci[CNT_GROUND, b] += 1
            h += 0.0
            continue
        living += 1
        if S[ROW_VZ, b, i] > 0.0:
            climbing += 1
        h += z * dt
        if explore:
            res_f = float(res)
            fx = np.ceil((x - p[P_MAP_MIN]) / p[P_MAP_CELL])
            fy = np.ceil((y - p[P_MAP_MIN]) / p[P_MAP_CELL])
            if fx > 0.0 and fx <= res_f and fy > 0.0 and fy <= res_f:
                visited[b, (int(fx) - 1) * res + int(fy) - 1] = True
        S[ROW_X, b, i], S[ROW_Y, b, i], S[ROW_Z, b, i] = nx, ny, nz
        S[ROW_VZ, b, i], S[ROW_HEADING, b, i] = vz, nh
        S[ROW_OMEGA, b, i], S[ROW_SPEED, b, i] = om, nv
    acci[CNT_LIVING, b] = living
    accf[ACC_FLIGHT, b] = accf[ACC_FLIGHT, b] + living * dt
    accf[ACC_HEIGHT, b] = h
    accf[ACC_THERMAL, b] = accf[ACC_THERMAL, b] + climbing * dt


@_jit
def advance(steps: int, step0: int, total: int, nfs: int, mfs: int, res: int, dt: float,
            stop_when_dead: bool, skip_finished: bool, S: np.ndarray, alive: np.ndarray,
            nb: np.ndarray, cnt: np.ndarray, th: np.ndarray, on: np.ndarray, par: np.ndarray,
            ext_on: np.ndarray, ext_cmd: np.ndarray, wag: np.ndarray, accf: np.ndarray,
            acci: np.ndarray, visited: np.ndarray, zs: np.ndarray, coh: np.ndarray,
            finished: np.ndarray, end_step: np.ndarray, sc: np.ndarray) -> int:
    """Fly up to ``steps`` steps after step ``step0``, in the seed's order per step: thermals
    fade, lists refresh (step 1 and every ``nfs``-th), then :func:`_step_run`; a run finishes
    after ``total`` steps or, with ``stop_when_dead``, when no glider is left. With
    ``skip_finished`` finished runs are no longer stepped and the call returns once every run
    has finished. Returns the steps flown. ``sc`` (5, B, N) is scratch."""
    B = S.shape[1]
    for k in range(steps):
        if skip_finished and finished.all():
            return k
        step = step0 + k + 1
        refresh = step == 1 or step % nfs == 0
        for b in range(B):
            if skip_finished and finished[b]:
                continue
            p = par[b]
            fade(th, on, b, p)
            headings(S, sc, b)
            if refresh:
                find_lists(S, alive, sc, b, p, nb, cnt, True)
            _step_run(b, step, dt, mfs, res, S, alive, nb, cnt, th, on, p, ext_on, ext_cmd,
                      wag, accf, acci, visited, zs, coh, sc)
            if step >= total or (stop_when_dead and acci[CNT_LIVING, b] == 0):
                if not finished[b]:
                    finished[b] = True
                    end_step[b] = step
    return steps


# -- elementwise entry points of the public wrappers (flat float64 arrays) ----------------------
@_jit
def cos_sin(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.empty_like(h), np.empty_like(h)
    for m in range(h.shape[0]):
        c[m], s[m] = math.cos(h[m]), math.sin(h[m])
    return c, s


@_jit
def sink_many(v: np.ndarray, bank: np.ndarray, a: np.ndarray, b: np.ndarray,
              c: np.ndarray) -> np.ndarray:
    out = np.empty_like(v)
    for m in range(v.shape[0]):
        out[m] = sink(v[m], bank[m], a[m], b[m], c[m])
    return out


@_jit
def command_many(ax: np.ndarray, ay: np.ndarray, c: np.ndarray, s: np.ndarray,
                 speed: np.ndarray, dt: float, g: np.ndarray, tbf: np.ndarray,
                 w: np.ndarray) -> np.ndarray:
    out = np.empty((2, ax.shape[0]))
    for m in range(ax.shape[0]):
        out[0, m], out[1, m] = command(ax[m], ay[m], c[m], s[m], speed[m], dt, g[m], tbf[m],
                                       w[m])
    return out


@_jit
def fly_many(X: np.ndarray, dt: float, par: np.ndarray) -> np.ndarray:
    """X (11, M): x, y, z, heading, bank, speed, v_cmd, b_cmd, w, cos, sin; par (M, len(PAR)).
    Returns (9, M): x, y, z, heading, omega, speed, bank, vz, ground (1.0/0.0)."""
    out = np.empty((9, X.shape[1]))
    for m in range(X.shape[1]):
        x, y, z, h, om, v, bank, vz, ground = fly(
            X[0, m], X[1, m], X[2, m], X[3, m], X[4, m], X[5, m], X[6, m], X[7, m], X[8, m],
            X[9, m], X[10, m], dt, par[m])
        out[0, m], out[1, m], out[2, m], out[3, m], out[4, m] = x, y, z, h, om
        out[5, m], out[6, m], out[7, m], out[8, m] = v, bank, vz, 1.0 if ground else 0.0
    return out


# -- the continuous flight model (sim_core.flight.FlightModel), on flat (row, M) arrays --------
#: rows of its per-vehicle table ``fp`` (FP_ROWS, M): bank τ s, bank rate limit rad/s, airspeed
#: τ s, airspeed rate limit m/s², polar A, B, C, g m/s², floor m, ceiling m
(FP_BANK_TAU, FP_BANK_RATE, FP_SPEED_TAU, FP_SPEED_RATE, FP_A, FP_B, FP_C, FP_G, FP_FLOOR,
 FP_CEIL) = range(10)
FP_ROWS = 10


@_jit
def _clip(x: float, lo: float, hi: float) -> float:
    """np.clip of a scalar (NaN stays NaN)."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@_jit
def flight_rhs(y: np.ndarray, u: np.ndarray, w: np.ndarray, fp: np.ndarray,
               glide: np.ndarray, out: np.ndarray) -> None:
    """out (6, M) = dy/dt of states y (6, M) under commands u (2, M) in updrafts w (M,) m/s
    (the right-hand side of sim_core.flight, its module docstring)."""
    for m in range(y.shape[1]):
        psi, bank, v = y[3, m], y[4, m], y[5, m]
        out[0, m] = v * math.cos(psi)
        out[1, m] = v * math.sin(psi)
        out[2, m] = (sink(v, bank, fp[FP_A, m], fp[FP_B, m], fp[FP_C, m]) + w[m]
                     if glide[m] else 0.0)
        out[3, m] = fp[FP_G, m] * math.tan(bank) / v
        out[4, m] = _clip((u[0, m] - bank) / fp[FP_BANK_TAU, m], -fp[FP_BANK_RATE, m],
                          fp[FP_BANK_RATE, m])
        out[5, m] = _clip((u[1, m] - v) / fp[FP_SPEED_TAU, m], -fp[FP_SPEED_RATE, m],
                          fp[FP_SPEED_RATE, m])


@_jit
def flight_stage(cur: np.ndarray, a: float, k: np.ndarray, out: np.ndarray) -> None:
    """out = cur + a·k (an RK4 stage's state), (6, M)."""
    for r in range(cur.shape[0]):
        for m in range(cur.shape[1]):
            out[r, m] = cur[r, m] + a * k[r, m]


@_jit
def flight_finish(cur: np.ndarray, k1: np.ndarray, k2: np.ndarray, k3: np.ndarray,
                  k4: np.ndarray, h: float, fp: np.ndarray, glide: np.ndarray,
                  live: np.ndarray, grounded: np.ndarray) -> None:
    """End an RK4 sub-step of ``h`` s in place: cur (6, M) += h/6 (k1 + 2 k2 + 2 k3 + k4) where
    ``live`` (M,), then a glider's height limits: above the ceiling it is held at it, below the
    floor at the floor, unless it reached z <= 0: then it keeps its state, leaves ``live`` and
    is marked in ``grounded`` (M,)."""
    h6 = h / 6.0
    for m in range(cur.shape[1]):
        if not live[m]:
            continue
        z = cur[2, m] + h6 * (((k1[2, m] + 2.0 * k2[2, m]) + 2.0 * k3[2, m]) + k4[2, m])
        if glide[m]:
            below = z < fp[FP_FLOOR, m]
            if below and z <= 0.0:
                grounded[m] = True
                live[m] = False
                continue
            if z > fp[FP_CEIL, m]:
                z = fp[FP_CEIL, m]
            elif below:
                z = fp[FP_FLOOR, m]
        for r in range(6):
            if r != 2:
                cur[r, m] = cur[r, m] + h6 * (((k1[r, m] + 2.0 * k2[r, m]) + 2.0 * k3[r, m])
                                              + k4[r, m])
        cur[2, m] = z


@_jit
def updraft_many(px: np.ndarray, py: np.ndarray, th: np.ndarray, on: np.ndarray) -> np.ndarray:
    """w m/s at points (B, M) for thermals (TH_ROWS, B, T)."""
    out = np.empty(px.shape)
    for b in range(px.shape[0]):
        for m in range(px.shape[1]):
            out[b, m] = updraft(px[b, m], py[b, m], th, on, b)
    return out


@_jit
def fade_many(th: np.ndarray, on: np.ndarray, par: np.ndarray) -> None:
    for b in range(th.shape[1]):
        fade(th, on, b, par[b])


@_jit
def lists_many(S: np.ndarray, alive: np.ndarray, par: np.ndarray, nb: np.ndarray,
               cnt: np.ndarray, owners_alive: bool) -> None:
    """Neighbour lists of every run from the state S (STATE_ROWS, B, N) (rows VX, VY are
    rewritten from heading and speed)."""
    cs = np.empty((2, S.shape[1], S.shape[2]))
    for b in range(S.shape[1]):
        headings(S, cs, b)
        find_lists(S, alive, cs, b, par[b], nb, cnt, owners_alive)


@_jit
def accel_many(G: np.ndarray, ids: np.ndarray, start: np.ndarray, own: np.ndarray,
               heading: np.ndarray, wag: np.ndarray, par: np.ndarray) -> np.ndarray:
    """Controller of M gliders: glider m's neighbours are columns ids[start[m]:start[m+1]] of
    G (6, V); own (6, M), heading (M,), wag (M,), par (M, len(PAR)). Returns (4, M): ax, ay,
    collision (1.0/0.0), ‖K_c·c‖."""
    M = own.shape[1]
    out = np.empty((4, M))
    for m in range(M):
        ax, ay, hit, cm = accel(G, ids[start[m]:], start[m + 1] - start[m], own[:, m],
                                heading[m], wag[m], par[m])
        out[0, m], out[1, m], out[2, m], out[3, m] = ax, ay, 1.0 if hit else 0.0, cm
    return out


@_jit
def controller(own: np.ndarray, obs: np.ndarray, p: np.ndarray, dt: float, wsign: float,
               w: float) -> tuple[float, float]:
    """(bank_cmd, airspeed_cmd) of one glider from own (6,) and its neighbours obs (K, 6),
    columns x, y, z, heading, speed, vz."""
    K = obs.shape[0]
    G = np.empty((6, K + 1))
    for q in range(K + 1):
        o = obs[q] if q < K else own
        G[ROW_VX, q] = o[4] * math.cos(o[3])
        G[ROW_VY, q] = o[4] * math.sin(o[3])
        G[ROW_X, q], G[ROW_Y, q], G[ROW_Z, q], G[ROW_VZ, q] = o[0], o[1], o[2], o[5]
    ax, ay, _, _ = accel(G, np.arange(K), K, G[:, K].copy(), own[3], wsign, p)
    v_cmd, b_cmd = command(ax, ay, math.cos(own[3]), math.sin(own[3]), own[4], dt, p[P_G],
                           p[P_TBF], w)
    return b_cmd, v_cmd
