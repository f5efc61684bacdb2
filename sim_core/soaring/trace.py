"""Per-step trajectories of one soaring run, and their ``.npz`` / CSV files.

CSV (what trajectory replay reads): header ``t,id,x,y,z,heading,bank,airspeed,vz,alive``, one
row per glider per recorded step, sorted by t then id. t s (0 = the initial state, then
k·dt after step k); id = glider index 0..N−1; x, y, z m (ENU); heading rad from +x; bank rad;
airspeed m/s; vz m/s (> 0 climbing); alive 1/0. A dead glider keeps its last state.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["CSV_COLUMNS", "Trace"]

CSV_COLUMNS: tuple[str, ...] = (
    "t", "id", "x", "y", "z", "heading", "bank", "airspeed", "vz", "alive",
)


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

    def save_npz(self, path: str | Path) -> None:
        """Write every array (compressed) under its field name."""
        np.savez_compressed(Path(path), **{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def load_npz(cls, path: str | Path) -> Trace:
        with np.load(Path(path)) as data:
            missing = sorted({f.name for f in fields(cls)} - set(data.files))
            if missing:
                raise ValueError(f"{path}: not a soaring trace, missing arrays {missing}")
            return cls(**{f.name: np.array(data[f.name]) for f in fields(cls)})

    def to_csv(self, path: str | Path) -> None:
        """Write the replay CSV (columns :data:`CSV_COLUMNS`)."""
        s, n = self.x.shape
        cols = [
            np.repeat(self.t, n),
            np.tile(np.arange(n), s),
            self.x.ravel(),
            self.y.ravel(),
            self.z.ravel(),
            self.heading.ravel(),
            self.bank.ravel(),
            self.airspeed.ravel(),
            self.vz.ravel(),
            self.alive.ravel().astype(np.float64),
        ]
        table = np.column_stack(cols) if s * n else np.zeros((0, len(CSV_COLUMNS)))
        fmt = ["%.6f", "%d"] + ["%.17g"] * 7 + ["%d"]
        np.savetxt(Path(path), table, delimiter=",", header=",".join(CSV_COLUMNS),
                   comments="", fmt=fmt)

    def save(self, path: str | Path) -> None:
        """``.csv`` → :meth:`to_csv`, anything else → :meth:`save_npz`."""
        p = Path(path)
        if p.suffix.lower() == ".csv":
            self.to_csv(p)
        else:
            self.save_npz(p)
