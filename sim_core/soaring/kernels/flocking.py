"""The seed's Boids in the kernels (spec §3.4, §3.6): one glider's controller from its
neighbours, the neighbour lists (k nearest within radius and field of view), and the headings'
cosines and velocity rows both read."""

from __future__ import annotations

import math

import numpy as np

from sim_core.soaring.kernels.arith import epow, jit, maximum, minimum, norm2, norm3, spow
from sim_core.soaring.kernels.layout import (
    P_AFP,
    P_ALI_P,
    P_ALI_W,
    P_ASC_IGN,
    P_ASC_MAX,
    P_CEIL,
    P_COH_P,
    P_FOV_LIMITED,
    P_HALF_FOV,
    P_HFP,
    P_K,
    P_KA,
    P_KC,
    P_KILL,
    P_KM,
    P_KS,
    P_KW,
    P_MIG_P,
    P_RADIUS,
    P_SEP_P,
    P_SEP_W,
    P_TX,
    P_TY,
    P_UNIFIED,
    ROW_HEADING,
    ROW_SPEED,
    ROW_VX,
    ROW_VY,
    ROW_VZ,
    ROW_X,
    ROW_Y,
    ROW_Z,
    W_MAX,
)


@jit
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
    height = spow(maximum(1.0 - own[ROW_Z] / p[P_CEIL], 0.0), p[P_HFP])
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
            dwc = maximum(minimum(G[ROW_VZ, j] - own[ROW_VZ], wmax), ign)
            weight = height * epow((dwc - ign) / (wmax - ign), p[P_AFP], n)
            ex_c, ey_c = weight * ex, weight * ey
        else:
            ex_c, ey_c = ex, ey
        w = minimum(epow(dxy / R, p[P_COH_P], n), W_MAX)
        cx += ex_c * w
        cy += ey_c * w
        rz = abs(dz)
        if rz < half_s or not unified:
            w = minimum(epow(d3 / R, p[P_SEP_P], n_s), W_MAX)
            sx += -ex * w
            sy += -ey * w
        if rz < half_a or not unified:
            w = minimum(epow(dxy / R, p[P_ALI_P], n_a), W_MAX)
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


@jit
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



@jit
def headings(S: np.ndarray, cs: np.ndarray, b: int) -> None:
    """cs[:, b] = (cos ψ, sin ψ) and the VX, VY rows of run b from heading and speed."""
    for i in range(S.shape[2]):
        c, s = math.cos(S[ROW_HEADING, b, i]), math.sin(S[ROW_HEADING, b, i])
        cs[0, b, i], cs[1, b, i] = c, s
        S[ROW_VX, b, i] = S[ROW_SPEED, b, i] * c
        S[ROW_VY, b, i] = S[ROW_SPEED, b, i] * s
