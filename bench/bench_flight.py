"""Continuous flight model (sim_core.flight): error against dt, and the seed law's metrics
with the seed's discrete step and with the continuous model (sim_core.continuous_swarm).

**Error vs dt.** 20 SB-XC gliders (default :class:`~sim_core.flight.FlightParams`) start level
at 10 m/s next to a 5 m/s thermal and fly 60 s of commands held for 0.5 s each (the seed
controller's rate): banks drawn from U(−15°, 15°), airspeeds from U(8, 13) m/s, a seeded rng.
Each is integrated with RK4 at step h (the commands change on step boundaries; steps longer
than the model's guard, half the 0.4 s bank time constant, are split: "h flown") and compared
with a reference integrated by scipy's DOP853 (rtol 1e-12) per 0.5 s interval. Errors are the
largest over the gliders at t = 60 s; the order is the slope of log error against log h.
The height error is first order: the seed's updraft profile jumps by 0.001·W at a thermal's
edge (docs/spec/seed_models.md §3.2), which a fixed step crosses at an arbitrary instant.

**Seed law, discrete vs continuous.** The packaged seed law (40 gliders, 7200 s) for the seeds
0..N−1 with ``echoloop swarm run`` (discrete, the seed's step) and ``--physics continuous`` (the
controller every 0.5 s, the gliders integrated at the given rate in between): mean ± sd over
the seeds, and the mean ± sd of the per-seed difference (continuous − discrete). Two more
continuous rows check where the differences come from: half the integration rate, and near-
instant bank and airspeed responses (τ = 0.05 s, no rate limits).

**Cost of a step.** CPU time of one :meth:`~sim_core.flight.FlightModel.step` (one RK4 step of
4 ms, the 250 Hz server's tick, in the seed's thermal field) and of one
:meth:`~sim_core.flight.FlightModel.outputs`, for the 9 vehicles of the demo and the seed law's
40 gliders: the median over 3 fresh processes of each one's median of 15 repeats of 500 calls,
beside the same probe on the numpy step it replaced (``git archive e35bd35 sim_core``),
the two alternating in the same run.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from bench._util import ROOT, git_tree, python_json, table
from sim_core.continuous_swarm import run_continuous
from sim_core.flight import FlightModel, FlightParams, X, Y, Z
from sim_core.rng import make_rng
from sim_core.soaring import Law, run_batch
from sim_core.soaring.thermals import spawn_thermals, updraft

TITLE = "Continuous flight: error vs dt, seed law discrete vs continuous"

#: The baseline of the step's cost: the last commit whose flight step was numpy, before the
#: compiled right-hand side and RK4 sub-step (sim_core/soaring/kernels/continuous.py, ``flight_*``).
BASELINE_COMMIT = "e35bd35"
#: probe runs per tree, alternating between the two trees
ROUNDS = 3

#: Timed in a subprocess against the ``sim_core`` in argv[1]: µs of CPU per step and per
#: outputs call, for each vehicle count, medians of 15 repeats of 500 calls after a warm-up.
_STEP_PROBE = """
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
from sim_core.flight import FlightModel, FlightParams
from sim_core.rng import make_rng
from sim_core.soaring import Law
from sim_core.soaring.thermals import spawn_thermals, updraft

law = Law()
th = spawn_thermals(law, make_rng(0))
out = {}
for n in (9, 40):
    model = FlightModel.from_params([FlightParams()] * n, glide=[True] * n,
                                    polar=(law.Sink_A, law.Sink_B, law.Sink_C), g=law.g)
    rng = make_rng(2)
    y = np.stack([rng.uniform(-500, 500, n), rng.uniform(-500, 500, n), np.full(n, 800.0),
                  rng.uniform(-3, 3, n), rng.uniform(-0.3, 0.3, n), np.full(n, 10.0)])
    u = np.stack([rng.uniform(-0.3, 0.3, n), rng.uniform(8, 13, n)])
    field = lambda xy: updraft(np.moveaxis(xy, 0, -1)[None], th)[0]
    def per_call(fn, k=500):
        fn()
        reps = []
        for _ in range(15):
            c0 = time.process_time()
            for _ in range(k):
                fn()
            reps.append((time.process_time() - c0) / k * 1e6)
        return statistics.median(reps)
    out[n] = [per_call(lambda: model.step(y, u, 0.004, updraft=field)),
              per_call(lambda: model.outputs(y, u, field(y[:2])))]
print(json.dumps(out))
"""

GLIDERS = 20
T_END = 60.0
HOLD = 0.5
STEPS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5)
SEEDS = 20
PHYSICS_HZ = 20.0
METRICS = ("surviving", "flightTime", "heightScore", "thermalUseScore", "explorationPercent",
           "collisionDeaths", "groundDeaths", "finalHeightAvg")


def _setup() -> tuple[FlightModel, np.ndarray, np.ndarray, Any]:
    law = Law().replace(thermals=[{"x": 60.0, "y": 0.0, "radius": 400.0, "strength": 5.0}])
    th = spawn_thermals(law, make_rng(0))

    def field(xy: np.ndarray) -> np.ndarray:
        return updraft(np.moveaxis(xy, 0, -1), th)

    model = FlightModel(bank_tau=FlightParams().bank_tau_s,
                        bank_rate_max=FlightParams().bank_rate_max,
                        speed_tau=FlightParams().speed_tau_s,
                        speed_rate_max=FlightParams().speed_rate_max, glide=True,
                        polar=(law.Sink_A, law.Sink_B, law.Sink_C), g=law.g)
    rng = make_rng(1)
    k = round(T_END / HOLD)
    cmds = np.stack([rng.uniform(-math.radians(15), math.radians(15), (k, 1, GLIDERS)),
                     rng.uniform(8.0, 13.0, (k, 1, GLIDERS))], axis=1)  # (K, 2, 1, N)
    y0 = np.zeros((6, 1, GLIDERS))
    y0[Y] = np.linspace(-200.0, 200.0, GLIDERS)
    y0[Z] = 1000.0
    y0[5] = 10.0
    return model, y0, cmds, field


def _fly(model: FlightModel, y0: np.ndarray, cmds: np.ndarray, field: Any, h: float) -> Any:
    y = y0
    n = round(HOLD / h)
    for u in cmds:
        y, _ = model.step(y, u, HOLD, substeps=n, updraft=field)
    return y


def _reference(model: FlightModel, y0: np.ndarray, cmds: np.ndarray, field: Any) -> Any:
    y = y0.ravel()
    for u in cmds:
        fun = model.fun(u, field)
        sol = solve_ivp(lambda t, v, f=fun: f(t, v.reshape(6, 1, GLIDERS)).ravel(), (0, HOLD),
                        y, method="DOP853", rtol=1e-12, atol=1e-10)
        y = sol.y[:, -1]
    return y.reshape(6, 1, GLIDERS)


def _convergence() -> str:
    model, y0, cmds, field = _setup()
    ref = _reference(model, y0, cmds, field)
    rows: list[list[Any]] = []
    prev: tuple[float, float] | None = None
    for h in STEPS:
        flown = HOLD / max(round(HOLD / h), math.ceil(HOLD / model.max_substep - 1e-9))
        c0 = time.process_time()
        y = _fly(model, y0, cmds, field, h)
        cpu = time.process_time() - c0
        pos = float(np.max(np.hypot(y[X] - ref[X], y[Y] - ref[Y])))
        dz = float(np.max(np.abs(y[Z] - ref[Z])))
        dpsi = float(np.max(np.abs(y[3] - ref[3])))
        order = ("" if prev is None or flown == prev[1]
                 else f"{math.log(pos / prev[0]) / math.log(flown / prev[1]):.2f}")
        rows.append([f"{h:g}", f"{flown:.4g}", f"{pos:.2e}", f"{dz:.2e}", f"{dpsi:.2e}", order,
                     f"{cpu * 1e3 / (T_END / flown):.3f}"])
        prev = (pos, flown)
    return table(["h s", "h flown s", "position error m", "height error m",
                  "heading error rad", "order (position)", "CPU ms per step (20 gliders)"],
                 rows)


#: (label, physics rate Hz, flight params) of the continuous rows; the last two check that
#: the differences come from the model, not from its integration: at half the rate the metrics
#: do not move; with near-instant bank and airspeed responses they return towards the seed's
CONTINUOUS = (
    (f"continuous, {PHYSICS_HZ:g} Hz", PHYSICS_HZ, FlightParams()),
    (f"continuous, {PHYSICS_HZ / 2:g} Hz", PHYSICS_HZ / 2, FlightParams()),
    ("continuous, τ 0.05 s, no rate limits, 40 Hz", 40.0,
     FlightParams(bank_tau_s=0.05, bank_rate_max=100.0, speed_tau_s=0.05,
                  speed_rate_max=100.0)),
)


def _metrics(seeds: list[int]) -> str:
    law = Law()
    c0 = time.process_time()
    results = [("discrete (seed step)", run_batch([law.replace(rngSeed=s) for s in seeds]))]
    cpu = [time.process_time() - c0]
    for label, hz, params in CONTINUOUS:
        c0 = time.process_time()
        results.append((label, run_continuous(law, seeds=seeds, physics_rate_hz=hz,
                                              flight=params)))
        cpu.append(time.process_time() - c0)
    rows = []
    for key in METRICS:
        vals = [np.array([getattr(r.metrics, key) for r in res], dtype=float)
                for _, res in results]
        diff = vals[1] - vals[0]
        rows.append([key, *(f"{np.nanmean(v):.4g} ± {np.nanstd(v, ddof=1):.3g}" for v in vals),
                     f"{np.nanmean(diff):+.3g} ± {np.nanstd(diff, ddof=1):.3g}"])
    rows.append(["CPU s (one batch)", *(f"{c:.0f}" for c in cpu), ""])
    return table(["metric", *(label for label, _ in results),
                  f"{results[1][0]} − discrete (paired)"], rows)


def _step_cost() -> str:
    runs: dict[str, list[dict[str, list[float]]]] = {"new": [], "old": []}
    with tempfile.TemporaryDirectory(prefix="echoloop-bench-") as tmp:
        trees = {"new": str(ROOT)}
        if git_tree(BASELINE_COMMIT, Path(tmp)):
            trees["old"] = tmp
        for _ in range(ROUNDS):  # interleaved: the machine's speed drifts within minutes
            for key, tree in trees.items():
                runs[key].append(python_json(_STEP_PROBE, tree))

    def cell(key: str, n: str, k: int) -> float:
        return statistics.median(r[n][k] for r in runs[key])

    rows = []
    for n in ("9", "40"):
        for k, what in enumerate(("step (RK4, 4 ms)", "outputs")):
            new = cell("new", n, k)
            if runs["old"]:
                old = cell("old", n, k)
                rows.append([n, what, f"{old:.1f}", f"{new:.1f}", f"{new / old:.2f}"])
            else:
                rows.append([n, what, "—", f"{new:.1f}", "—"])
    return table(["vehicles", "call", f"numpy ({BASELINE_COMMIT}) µs", "compiled µs",
                  "compiled / numpy"], rows)


def run(out_dir: Path) -> str:
    cost = _step_cost()
    conv = _convergence()
    text = _metrics(list(range(SEEDS)))
    return (f"{__doc__}\n{conv}\n\nSeed law, seeds 0..{SEEDS - 1} (mean ± sd):\n\n{text}\n"
            f"\nCost of a step (CPU µs per call, same run):\n\n{cost}\n")
