"""Parameter grids: a grid × a base law → the laws of its runs.

A grid (seed 002 "megarun" form) is a mapping of law parameter names to non-empty lists of
values; the runs are the Cartesian product, in mapping order with the last key varying fastest.
Grid files and the run key of a results table are :mod:`hil_bridge.files.soaring`.

Running a grid is :func:`~sim_core.soaring.run_batch` on its laws; executing a sweep (results
tables, worker processes, a dask cluster) is :mod:`hil_bridge.tools.sweep` (``echoloop swarm
sweep``).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import fields
from typing import Any

from sim_core.config import ConfigError
from sim_core.soaring.law import Law

__all__ = ["check_grid", "expand_grid"]

_LAW_FIELDS = {f.name for f in fields(Law)}
_STRUCTURED = {"thermals", "agents"}


def check_grid(data: Any, *, where: str = "grid") -> dict[str, list[Any]]:
    """Validate a grid mapping: non-empty, law parameter names (not the structured ``thermals``
    and ``agents``) to non-empty lists; ``ConfigError`` naming ``where`` and the key."""
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
