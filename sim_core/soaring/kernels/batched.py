"""The kernels' entry points for the public wrappers of :mod:`sim_core.soaring` (flat float64
arrays, one element per glider or point): the scalar kernels applied elementwise, and the
controller of one glider from its observed neighbours."""

from __future__ import annotations

import math

import numpy as np

from sim_core.soaring.kernels.arith import jit
from sim_core.soaring.kernels.flocking import accel, find_lists, headings
from sim_core.soaring.kernels.kinematics import command, fly, sink
from sim_core.soaring.kernels.layout import (
    P_G,
    P_TBF,
    ROW_VX,
    ROW_VY,
    ROW_VZ,
    ROW_X,
    ROW_Y,
    ROW_Z,
)
from sim_core.soaring.kernels.updrafts import fade, updraft


@jit
def cos_sin(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.empty_like(h), np.empty_like(h)
    for m in range(h.shape[0]):
        c[m], s[m] = math.cos(h[m]), math.sin(h[m])
    return c, s


@jit
def sink_many(v: np.ndarray, bank: np.ndarray, a: np.ndarray, b: np.ndarray,
              c: np.ndarray) -> np.ndarray:
    out = np.empty_like(v)
    for m in range(v.shape[0]):
        out[m] = sink(v[m], bank[m], a[m], b[m], c[m])
    return out


@jit
def command_many(ax: np.ndarray, ay: np.ndarray, c: np.ndarray, s: np.ndarray,
                 speed: np.ndarray, dt: float, g: np.ndarray, tbf: np.ndarray,
                 w: np.ndarray) -> np.ndarray:
    out = np.empty((2, ax.shape[0]))
    for m in range(ax.shape[0]):
        out[0, m], out[1, m] = command(ax[m], ay[m], c[m], s[m], speed[m], dt, g[m], tbf[m],
                                       w[m])
    return out


@jit
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



@jit
def updraft_many(px: np.ndarray, py: np.ndarray, th: np.ndarray, on: np.ndarray) -> np.ndarray:
    """w m/s at points (B, M) for thermals (TH_ROWS, B, T)."""
    out = np.empty(px.shape)
    for b in range(px.shape[0]):
        for m in range(px.shape[1]):
            out[b, m] = updraft(px[b, m], py[b, m], th, on, b)
    return out


@jit
def fade_many(th: np.ndarray, on: np.ndarray, par: np.ndarray) -> None:
    for b in range(th.shape[1]):
        fade(th, on, b, par[b])


@jit
def lists_many(S: np.ndarray, alive: np.ndarray, par: np.ndarray, nb: np.ndarray,
               cnt: np.ndarray, owners_alive: bool) -> None:
    """Neighbour lists of every run from the state S (STATE_ROWS, B, N) (rows VX, VY are
    rewritten from heading and speed)."""
    cs = np.empty((2, S.shape[1], S.shape[2]))
    for b in range(S.shape[1]):
        headings(S, cs, b)
        find_lists(S, alive, cs, b, par[b], nb, cnt, owners_alive)


@jit
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


@jit
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
