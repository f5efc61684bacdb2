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

from hil_bridge.files.config import load_npz

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
        """Read a trace written by :meth:`save_npz`; ``ConfigError``/``ValueError`` naming the
        file for a damaged archive, a missing array, shapes that disagree or a non-finite
        value."""
        data = load_npz(path)
        missing = sorted({f.name for f in fields(cls)} - set(data))
        if missing:
            raise ValueError(f"{path}: not a soaring trace, missing arrays {missing}")
        t = data["t"]
        steps = t.shape[0] if t.ndim == 1 else -1
        agents = data["x"].shape[-1] if data["x"].ndim == 2 else -1
        for f in fields(cls):
            arr = data[f.name]
            if f.name.startswith("thermal_") and f.name != "thermal_strength":
                want: tuple[int, ...] = (data["thermal_x"].shape[0],)
            elif f.name == "thermal_strength":
                want = (steps, data["thermal_x"].shape[0])
            else:
                want = (steps,) if f.name == "t" else (steps, agents)
            if steps < 0 or agents < 0 or arr.shape != want:
                raise ValueError(f"{path}: array {f.name!r} has shape {arr.shape}; a trace of "
                                 f"{steps} steps and {agents} gliders needs {want}")
            if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
                row = int(np.argwhere(~np.isfinite(arr))[0][0])
                raise ValueError(f"{path}: array {f.name!r} is not finite at step {row}")
        return cls(**{f.name: data[f.name] for f in fields(cls)})

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
