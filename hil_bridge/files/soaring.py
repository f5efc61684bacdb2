"""Soaring files: law and grid YAML files (and the packaged ones), traces as ``.npz``/CSV, and
the run key of a sweep's results table.

* Law file: a mapping of seed 002 parameter names (:class:`sim_core.soaring.Law`; missing keys
  take the defaults); ``"default"`` names the packaged seed law ``law_40survivors.yaml``.
* Grid file (seed 002 "megarun" form, e.g. the packaged ``megarun7_grid.yaml``): a mapping of
  law parameter names to non-empty lists of values (:func:`sim_core.soaring.sweep.check_grid`).
* Trace ``.npz``: every array of a :class:`sim_core.soaring.Trace` under its field name.
* Trace CSV (what trajectory replay reads): header ``t,id,x,y,z,heading,bank,airspeed,vz,alive``,
  one row per glider per recorded step, sorted by t then id. t s (0 = the initial state, then
  k·dt after step k); id = glider index 0..N−1; x, y, z m (ENU); heading rad from +x; bank rad;
  airspeed m/s; vz m/s (> 0 climbing); alive 1/0. A dead glider keeps its last state.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.files.config import load_npz, load_yaml
from sim_core.config import ConfigError, apply_overrides
from sim_core.soaring.law import DEFAULT_LAW, Law
from sim_core.soaring.sweep import check_grid
from sim_core.soaring.trace import Trace

__all__ = [
    "TRACE_CSV_COLUMNS",
    "default_grid_path",
    "default_law_path",
    "load_grid",
    "load_law",
    "load_trace",
    "run_key",
    "save_trace",
    "save_trace_npz",
    "write_trace_csv",
]

TRACE_CSV_COLUMNS: tuple[str, ...] = (
    "t", "id", "x", "y", "z", "heading", "bank", "airspeed", "vz", "alive",
)


def _data(name: str) -> Path:
    return Path(str(resources.files("hil_bridge.files") / "data" / "soaring" / name))


def default_law_path() -> Path:
    """Path of the packaged seed law ``law_40survivors.yaml``."""
    return _data("law_40survivors.yaml")


def default_grid_path() -> Path:
    """Path of the packaged Megarun 7 grid ``megarun7_grid.yaml`` (18,000 runs)."""
    return _data("megarun7_grid.yaml")


def load_law(path: str | Path, overrides: Mapping[str, Any] | None = None) -> Law:
    """Load a law file (``"default"`` = the packaged seed law) and apply overrides.

    ``overrides`` maps parameter names to values (already parsed, e.g. by
    :func:`hil_bridge.files.config.parse_override` from ``--set KEY=VALUE``); they take
    precedence over the file, which takes precedence over the defaults. ``ConfigError`` names
    the file and the key.
    """
    p = default_law_path() if str(path) == DEFAULT_LAW else Path(path)
    data = load_yaml(p)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{p}: expected a mapping of law parameters, got {data!r}")
    merged = apply_overrides(data, dict(overrides or {}))
    try:
        return Law.from_dict(merged)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None


def load_grid(path: str | Path) -> dict[str, list[Any]]:
    """Read and check a grid file: a non-empty mapping of law keys to non-empty lists."""
    data = load_yaml(path)
    return check_grid(data, where=str(path))


def run_key(law: Law) -> str:
    """Stable 16-hex-digit hash of a run's full law (its seed is ``rngSeed``): the ``runKey``
    column of a sweep's results table."""
    text = json.dumps(law.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def save_trace_npz(trace: Trace, path: str | Path) -> None:
    """Write every array of ``trace`` (compressed) under its field name."""
    np.savez_compressed(Path(path), **{f.name: getattr(trace, f.name) for f in fields(trace)})


def load_trace(path: str | Path) -> Trace:
    """Read a trace written by :func:`save_trace_npz`; ``ConfigError``/``ValueError`` naming the
    file for a damaged archive, a missing array, shapes that disagree or a non-finite value."""
    data = load_npz(path)
    missing = sorted({f.name for f in fields(Trace)} - set(data))
    if missing:
        raise ValueError(f"{path}: not a soaring trace, missing arrays {missing}")
    t = data["t"]
    steps = t.shape[0] if t.ndim == 1 else -1
    agents = data["x"].shape[-1] if data["x"].ndim == 2 else -1
    for f in fields(Trace):
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
    return Trace(**{f.name: data[f.name] for f in fields(Trace)})


def write_trace_csv(trace: Trace, path: str | Path) -> None:
    """Write the replay CSV (columns :data:`TRACE_CSV_COLUMNS`)."""
    s, n = trace.x.shape
    cols = [
        np.repeat(trace.t, n),
        np.tile(np.arange(n), s),
        trace.x.ravel(),
        trace.y.ravel(),
        trace.z.ravel(),
        trace.heading.ravel(),
        trace.bank.ravel(),
        trace.airspeed.ravel(),
        trace.vz.ravel(),
        trace.alive.ravel().astype(np.float64),
    ]
    table = np.column_stack(cols) if s * n else np.zeros((0, len(TRACE_CSV_COLUMNS)))
    fmt = ["%.6f", "%d"] + ["%.17g"] * 7 + ["%d"]
    np.savetxt(Path(path), table, delimiter=",", header=",".join(TRACE_CSV_COLUMNS),
               comments="", fmt=fmt)


def save_trace(trace: Trace, path: str | Path) -> None:
    """``.csv`` → :func:`write_trace_csv`, anything else → :func:`save_trace_npz`."""
    p = Path(path)
    if p.suffix.lower() == ".csv":
        write_trace_csv(trace, p)
    else:
        save_trace_npz(trace, p)
