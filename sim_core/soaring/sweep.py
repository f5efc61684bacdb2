"""Parameter grids: a grid × a base law → the laws of its runs, each with a stable key.

Grid file (seed 002 "megarun" form, e.g. ``data/megarun7_grid.yaml``): a mapping of law
parameter names to non-empty lists of values; the runs are the Cartesian product, in file order
with the last key varying fastest. :func:`run_key` is a stable hash of a run's full law (its
seed is ``rngSeed``), the row key of a results table.

Running a grid is :func:`~sim_core.soaring.run_batch` on its laws; executing a sweep (results
tables, worker processes, a dask cluster) is :mod:`hil_bridge.tools.sweep` (``echoloop swarm
sweep``).
"""

from __future__ import annotations

import hashlib
import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

from hil_bridge.files.config import load_yaml
from sim_core.config import ConfigError
from sim_core.soaring.law import Law

__all__ = ["check_grid", "expand_grid", "load_grid", "run_key"]

_LAW_FIELDS = {f.name for f in fields(Law)}
_STRUCTURED = {"thermals", "agents"}


def load_grid(path: str | Path) -> dict[str, list[Any]]:
    """Read and check a grid file: a non-empty mapping of law keys to non-empty lists."""
    data = load_yaml(path)
    return check_grid(data, where=str(path))


def check_grid(data: Any, *, where: str = "grid") -> dict[str, list[Any]]:
    """Validate a grid mapping (see :func:`load_grid`)."""
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(f"{where}: expected a non-empty mapping of law parameters to lists")
    grid: dict[str, list[Any]] = {}
    for key, values in data.items():
        if key not in _LAW_FIELDS or key in _STRUCTURED:
            raise ConfigError(
                f"{where}: unknown grid key {key!r}; expected law parameters such as "
                "numAgents, numThermals, rngSeed, cohesion, separation, alignment, migration"
            )
        if not isinstance(values, list):
            raise ConfigError(f"{where}: {key}: expected a list of values, got {values!r}")
        if not values:
            raise ConfigError(f"{where}: {key}: empty list, the grid would have no runs")
        grid[str(key)] = list(values)
    return grid


def expand_grid(base: Law, grid: Mapping[str, Sequence[Any]]) -> list[tuple[dict[str, Any], Law]]:
    """(swept inputs, law) for every point of the grid, validated (errors name the key)."""
    keys = list(grid)
    base_dict = base.to_dict()
    out: list[tuple[dict[str, Any], Law]] = []
    for combo in itertools.product(*(grid[k] for k in keys)):
        inputs = dict(zip(keys, combo, strict=True))
        try:
            law = Law.from_dict({**base_dict, **inputs})
        except ConfigError as exc:
            raise ConfigError(f"grid point {inputs}: {exc}") from None
        out.append((inputs, law))
    return out


def run_key(law: Law) -> str:
    """Stable 16-hex-digit hash of a run's full law (its seed is ``rngSeed``)."""
    text = json.dumps(law.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
