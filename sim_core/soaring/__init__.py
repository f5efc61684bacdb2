"""Thermal-soaring swarm of seed 002 (Pooley et al. 2023): thermals, SB-XC gliders, hawk-inspired
Boids ("Unified" and "Baseline"), metrics, batched runs and parameter sweeps.

Formulas and their sources: ``docs/spec/seed_models.md`` §3; user notes: ``docs/soaring.md``.
"""

from sim_core.soaring.boids import (
    CONTROLLERS,
    GliderObs,
    boids_accel,
    controller_command,
    find_neighbors,
    law_params,
)
from sim_core.soaring.glider import accel_to_command, glider_step, sink_rate
from sim_core.soaring.law import (
    Law,
    PinnedAgent,
    PinnedThermal,
    default_grid_path,
    default_law_path,
)
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
from sim_core.soaring.thermals import Thermals, spawn_thermals, updraft
from sim_core.soaring.trace import CSV_COLUMNS, Trace

__all__ = [
    "CONTROLLERS",
    "CSV_COLUMNS",
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
    "default_grid_path",
    "default_law_path",
    "find_neighbors",
    "glider_step",
    "law_params",
    "run",
    "run_batch",
    "sink_rate",
    "spawn_thermals",
    "updraft",
]
