"""Thermal-soaring swarm of seed 002 (Pooley et al. 2023): thermals, SB-XC gliders, hawk-inspired
Boids ("Unified" and "Baseline"), metrics, batched runs and parameter sweeps.

Formulas and their sources: ``docs/spec/seed_models.md`` §3; user notes: ``docs/soaring.md``.
The physics is compiled (:mod:`sim_core.soaring.kernels`); :func:`warm_up` compiles it, or loads
it from numba's on-disk cache, ahead of first use.
"""

import numpy as np

from sim_core.soaring.boids import (
    CONTROLLERS,
    GliderObs,
    boids_accel,
    controller_command,
    find_neighbors,
    law_params,
)
from sim_core.soaring.glider import accel_to_command, glider_step, sink_rate
from sim_core.soaring.law import Law, PinnedAgent, PinnedThermal
from sim_core.soaring.swarm import (
    METRIC_NAMES,
    Commands,
    Metrics,
    RunResult,
    SwarmSim,
    SwarmState,
    run,
    run_batch,
)
from sim_core.soaring.thermals import Thermals, fade_step, spawn_thermals, updraft
from sim_core.soaring.trace import Trace

__all__ = [
    "CONTROLLERS",
    "METRIC_NAMES",
    "Commands",
    "GliderObs",
    "Law",
    "Metrics",
    "PinnedAgent",
    "PinnedThermal",
    "RunResult",
    "SwarmSim",
    "SwarmState",
    "Thermals",
    "Trace",
    "accel_to_command",
    "boids_accel",
    "controller_command",
    "find_neighbors",
    "glider_step",
    "law_params",
    "run",
    "run_batch",
    "sink_rate",
    "spawn_thermals",
    "updraft",
    "warm_up",
]


def warm_up() -> None:
    """Compile every soaring kernel, once per installation and CPU (~10 s CPU), or load it from
    the on-disk cache (~0.3 s CPU per process), through the public functions, so that no later
    call pays it: call it before a realtime loop, or after installing
    (:func:`sim_core.flight.warm_up` does this and the continuous flight model's kernels)."""
    law = Law().replace(numAgents=3, numThermals=2, totalTime=1.0)
    sim = SwarmSim(law, seed=0)
    sim.step()
    th = sim.thermals
    updraft(np.zeros((2, 2)), th)
    controller_command(GliderObs(0.0, 0.0, 1000.0, 0.0, 10.0, 0.0),
                       [GliderObs(50.0, 0.0, 1000.0, 0.0, 10.0, 1.0)], law)
    bank, speed = accel_to_command(1.0, 0.5, 0.0, 10.0, dt=law.dt, g=law.g,
                                   thermal_bank_factor=0.0, updraft=0.0)
    glider_step(0.0, 0.0, 1000.0, 0.0, 0.0, 10.0, bank, speed, 0.0, dt=law.dt, g=law.g,
                speed_min=8.0, speed_max=13.0, bank_min=-0.2, bank_max=0.2,
                sink_abc=(law.Sink_A, law.Sink_B, law.Sink_C), ceiling=2600.0, floor=0.0)
    sink_rate(10.0, 0.0, law.Sink_A, law.Sink_B, law.Sink_C)
    P = law_params([law])
    s = sim.state
    find_neighbors(s.x, s.y, s.z, s.heading, s.alive, P, width=2)
    boids_accel({k: getattr(s, k) for k in ("x", "y", "z", "heading", "speed", "vz")},
                {k: np.zeros(0) for k in ("x", "y", "z", "vx", "vy", "vz")},
                np.zeros(0, dtype=np.intp), P, np.zeros((1, 3)))
    fade_step(th, by_time=P["fade_by_time"], rate=P["fade_rate"], top=P["fade_top"],
              bottom=P["fade_bottom"], dt=law.dt)
