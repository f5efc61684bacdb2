"""The swarm step of the kernels (spec §3.1): one run's controller, flight, deaths and metrics
for a step, and :func:`advance`, which flies every run of a batch step after step in the seed's
order."""

from __future__ import annotations

import numpy as np

from sim_core.soaring.kernels.arith import jit
from sim_core.soaring.kernels.flocking import accel, find_lists, headings
from sim_core.soaring.kernels.kinematics import command, fly
from sim_core.soaring.kernels.layout import (
    ACC_FLIGHT,
    ACC_HEIGHT,
    ACC_THERMAL,
    CNT_COLL,
    CNT_GROUND,
    CNT_LIVING,
    P_G,
    P_MAP_CELL,
    P_MAP_MIN,
    P_TBF,
    ROW_BANK,
    ROW_HEADING,
    ROW_OMEGA,
    ROW_SPEED,
    ROW_VZ,
    ROW_X,
    ROW_Y,
    ROW_Z,
)
from sim_core.soaring.kernels.updrafts import fade, updraft


@jit
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


@jit
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

