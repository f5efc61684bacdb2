"""Per-step trajectories of one soaring run (its ``.npz`` and CSV files:
:mod:`hil_bridge.files.soaring`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Trace"]


@dataclass(frozen=True, slots=True)
class Trace:
    """Recorded states: t (S,) s; x, y, z, heading, bank, airspeed, vz, cohesion (‖K_c·c‖)
    and alive, each (S, N); the thermals' centres and radii (T,) and strength (S, T) m/s."""

    t: NDArray[np.float64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    z: NDArray[np.float64]
    heading: NDArray[np.float64]
    bank: NDArray[np.float64]
    airspeed: NDArray[np.float64]
    vz: NDArray[np.float64]
    alive: NDArray[np.bool_]
    cohesion: NDArray[np.float64]
    thermal_x: NDArray[np.float64]
    thermal_y: NDArray[np.float64]
    thermal_radius: NDArray[np.float64]
    thermal_strength: NDArray[np.float64]

    @property
    def n_steps(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_agents(self) -> int:
        return int(self.x.shape[1])
