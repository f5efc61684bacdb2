"""The simulation law: seed 002's parameter set as one frozen dataclass.

Field names are the seed's (``Law_40SurvivorsExample.xlsx`` sheet 1, see
``docs/spec/seed_models.md`` §3.9); defaults are that law (also shipped as the law file
``law_40survivors.yaml``, read by :func:`hil_bridge.files.soaring.load_law`).
Units are SI (m, s, rad). A law file may omit keys (they take the defaults) but may not contain
unknown keys. Extensions beyond the seed (all defaulting to the seed's behaviour):

* ``controller``: ``"unified"`` (``agentControl_Unified``) or ``"baseline"``.
* ``migrationTarget``: the migration target (x, y), metres (the seed hard-codes (0, 0)).
* ``thermalFadeMode``: ``"steps"`` (the seed: rate per step, plateaus in steps, so behaviour
  changes with dt) or ``"seconds"`` (``thermalFadeRatePerSecond`` m/s per s, plateaus
  ``thermalMinPlateauSeconds`` / ``thermalMaxPlateauSeconds``; identical to the seed at dt 0.5).
* ``bankRateMax`` (rad/s) and ``speedRateMax`` (m/s²): optional rate limits applied to every
  bank and airspeed command (``null`` = none, as in the seed).
* ``thermals``: pinned thermals ``[{x, y, radius, strength, fade}]`` that replace the random ones
  (``numThermals`` is then ignored). A pinned thermal with ``fade: true`` has W_max = strength
  and starts at its top plateau.
* ``agents``: pinned gliders ``[{x, y, z, heading, speed}]`` that replace the random spawn
  (``numAgents`` is then ignored; heading in rad from +x).

Precedence: ``--set`` overrides > law file > packaged defaults, merged before validation
(:func:`sim_core.config.apply_overrides`, then :meth:`Law.from_dict`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from sim_core.config import ConfigError, from_dict

__all__ = [
    "DEFAULT_LAW",
    "Law",
    "PinnedAgent",
    "PinnedThermal",
]

#: the name of the packaged seed law where a law file is named
DEFAULT_LAW = "default"


@dataclass(frozen=True, slots=True)
class PinnedThermal:
    """A thermal at a fixed place: centre (x, y) m, radius m, strength W m/s."""

    x: float
    y: float
    radius: float
    strength: float
    fade: bool = False

    def __post_init__(self) -> None:
        if not self.radius > 0:
            raise ValueError(f"radius must be > 0 m, got {self.radius}")


@dataclass(frozen=True, slots=True)
class PinnedAgent:
    """A glider's initial state: position m, heading rad from +x, airspeed m/s."""

    x: float
    y: float
    z: float
    heading: float = 0.0
    speed: float = 10.0


Pair = tuple[float, float]

#: the largest swarm a law may ask for (pairwise neighbour terms grow as N²)
MAX_AGENTS = 10_000
#: the most thermals a law may ask for
MAX_THERMALS = 10_000


@dataclass(frozen=True, slots=True)
class Law:
    """All parameters of one soaring run (seed 002 names; defaults = Law_40SurvivorsExample)."""

    dt: float = 0.5
    totalTime: float = 7200.0
    numAgents: int = 40
    numThermals: int = 9
    stopWhenDead: bool = True
    neighborFrameSkip: int = 10
    rngSeed: int = 2
    mapSize: Pair = (-4000.0, 4000.0)
    agentCeiling: float = 2600.0
    agentFloor: float = 0.0
    agentSpawnPosRange: tuple[Pair, Pair] = ((-3000.0, -3000.0), (3000.0, 3000.0))
    agentSpawnAltiRange: Pair = (1100.0, 1500.0)
    agentSpawnVelRange: tuple[Pair, Pair] = ((8.0, 0.0), (13.0, 0.0))
    g: float = 9.81
    cohesion: float = 1000.0
    heightFactorPower: float = 1.0
    cohesionAscensionIgnore: float = 0.5
    cohesionAscensionMax: float = 10.0
    ascensionFactorPower: float = 2.0
    cohPower: float = 0.0
    separation: float = 0.3
    separationHeightWidth: float = 200.0
    sepPower: float = -2.0
    alignment: float = 0.001
    alignmentHeightWidth: float = 200.0
    aliPower: float = -2.0
    migration: float = 1.0e-21
    migPower: float = 5.0
    waggle: float = 0.0
    waggleDurationRange: Pair = (0.3, 0.5)
    thermalBankFactor: float = 0.0
    neighborRadius: float = 1000.0
    k: int = 10
    fov: float = 5.759586531581287
    forwardSpeedMin: float = 8.0
    forwardSpeedMax: float = 13.0
    bankMin: float = -0.2617993877991494
    bankMax: float = 0.2617993877991494
    Sink_A: float = -0.01843
    Sink_B: float = 0.3782
    Sink_C: float = -2.3782
    collisionKillDistance: float = 4.0
    thermalSpawnRange: Pair = (-3000.0, 3000.0)
    thermalSpawnAttempts: int = 50
    thermalSpeedMin: float = 0.0
    thermalSpeedMax: float = 0.0
    thermalRadiusMin: float = 300.0
    thermalRadiusMax: float = 550.0
    thermalStrengthMin: float = 3.0
    thermalStrengthMax: float = 10.0
    thermalFadeRate: float = 0.005
    thermalMinPlateauTime: int = 800
    thermalMaxPlateauTime: int = 600
    mapDivResolution: int = 10
    mapDivFrameSkip: int = 10
    controller: Literal["unified", "baseline"] = "unified"
    migrationTarget: Pair = (0.0, 0.0)
    thermalFadeMode: Literal["steps", "seconds"] = "steps"
    thermalFadeRatePerSecond: float = 0.01
    thermalMinPlateauSeconds: float = 400.0
    thermalMaxPlateauSeconds: float = 300.0
    bankRateMax: float | None = None
    speedRateMax: float | None = None
    thermals: tuple[PinnedThermal, ...] | None = None
    agents: tuple[PinnedAgent, ...] | None = None

    def __post_init__(self) -> None:
        def need(ok: bool, key: str, what: str) -> None:
            if not ok:
                raise ConfigError(f"{key}: expected {what}, got {getattr(self, key)!r}")

        need(self.dt > 0, "dt", "a time step > 0 s")
        need(self.totalTime >= 0, "totalTime", "a duration >= 0 s")
        steps = self.totalTime / self.dt
        need(
            abs(steps - round(steps)) <= 1e-9 * max(1.0, steps),
            "totalTime",
            f"a whole number of steps of dt={self.dt}",
        )
        need(0 <= self.numAgents <= MAX_AGENTS, "numAgents", f"an integer in 0..{MAX_AGENTS}")
        need(0 <= self.numThermals <= MAX_THERMALS, "numThermals",
             f"an integer in 0..{MAX_THERMALS}")
        need(self.neighborFrameSkip >= 1, "neighborFrameSkip", "an integer >= 1")
        need(self.rngSeed >= 0, "rngSeed", "an integer >= 0")
        need(self.mapSize[0] < self.mapSize[1], "mapSize", "[min, max] with min < max")
        need(self.agentCeiling > self.agentFloor, "agentCeiling", "a ceiling above agentFloor")
        need(self.agentFloor >= 0, "agentFloor", "a floor >= 0 m")
        for key in ("agentSpawnAltiRange", "waggleDurationRange", "thermalSpawnRange"):
            lo, hi = getattr(self, key)
            need(lo <= hi, key, "[min, max] with min <= max")
        for key in ("agentSpawnPosRange", "agentSpawnVelRange"):
            lo2, hi2 = getattr(self, key)
            need(lo2[0] <= hi2[0] and lo2[1] <= hi2[1], key, "[[min...], [max...]] rows")
        need(self.agentSpawnVelRange[0][0] > 0, "agentSpawnVelRange", "forward speeds > 0")
        need(self.g > 0, "g", "gravity > 0 m/s^2")
        need(
            self.cohesionAscensionMax > self.cohesionAscensionIgnore,
            "cohesionAscensionMax",
            "a value above cohesionAscensionIgnore",
        )
        need(self.heightFactorPower >= 0, "heightFactorPower", "a power >= 0")
        need(self.ascensionFactorPower >= 0, "ascensionFactorPower", "a power >= 0")
        need(self.separationHeightWidth >= 0, "separationHeightWidth", "a width >= 0 m")
        need(self.alignmentHeightWidth >= 0, "alignmentHeightWidth", "a width >= 0 m")
        need(self.waggleDurationRange[0] > 0, "waggleDurationRange", "durations > 0 s")
        need(self.neighborRadius > 0, "neighborRadius", "a radius > 0 m")
        need(self.k >= 0, "k", "an integer >= 0")
        need(0 < self.fov <= 2 * math.pi + 1e-9, "fov", "a field of view in (0, 2*pi] rad")
        need(self.forwardSpeedMin > 0, "forwardSpeedMin", "a speed > 0 m/s")
        need(self.forwardSpeedMax >= self.forwardSpeedMin, "forwardSpeedMax", ">= forwardSpeedMin")
        half_pi = math.pi / 2
        need(-half_pi < self.bankMin <= 0, "bankMin", "a bank angle in (-pi/2, 0] rad")
        need(0 <= self.bankMax < half_pi, "bankMax", "a bank angle in [0, pi/2) rad")
        need(self.collisionKillDistance >= 0, "collisionKillDistance", "a distance >= 0 m")
        need(self.thermalSpawnAttempts >= 1, "thermalSpawnAttempts", "an integer >= 1")
        need(
            self.thermalSpeedMin == 0 and self.thermalSpeedMax == 0,
            "thermalSpeedMax",
            "0 (moving thermals are unused by the seed's runs and not modelled)",
        )
        need(
            0 < self.thermalRadiusMin <= self.thermalRadiusMax,
            "thermalRadiusMin",
            "0 < thermalRadiusMin <= thermalRadiusMax",
        )
        need(
            0 <= self.thermalStrengthMin < self.thermalStrengthMax,
            "thermalStrengthMin",
            "0 <= thermalStrengthMin < thermalStrengthMax",
        )
        need(self.thermalFadeRate >= 0, "thermalFadeRate", "a rate >= 0 m/s per step")
        need(self.thermalFadeRatePerSecond >= 0, "thermalFadeRatePerSecond", "a rate >= 0")
        need(self.thermalMinPlateauTime >= 0, "thermalMinPlateauTime", "steps >= 0")
        need(self.thermalMaxPlateauTime >= 0, "thermalMaxPlateauTime", "steps >= 0")
        need(self.thermalMinPlateauSeconds >= 0, "thermalMinPlateauSeconds", "seconds >= 0")
        need(self.thermalMaxPlateauSeconds >= 0, "thermalMaxPlateauSeconds", "seconds >= 0")
        need(self.mapDivResolution >= 1, "mapDivResolution", "an integer >= 1")
        need(self.mapDivFrameSkip >= 1, "mapDivFrameSkip", "an integer >= 1")
        need(self.bankRateMax is None or self.bankRateMax > 0, "bankRateMax", "null or > 0")
        need(self.speedRateMax is None or self.speedRateMax > 0, "speedRateMax", "null or > 0")
        for i, agent in enumerate(self.agents or ()):
            if not self.forwardSpeedMin <= agent.speed <= self.forwardSpeedMax:
                raise ConfigError(
                    f"agents[{i}].speed: expected a speed in [forwardSpeedMin, forwardSpeedMax]"
                    f" = [{self.forwardSpeedMin}, {self.forwardSpeedMax}] m/s, got {agent.speed!r}"
                )
            if not self.agentFloor < agent.z <= self.agentCeiling:
                raise ConfigError(
                    f"agents[{i}].z: expected a height in (agentFloor, agentCeiling]"
                    f" = ({self.agentFloor}, {self.agentCeiling}] m, got {agent.z!r}"
                )

    # -- derived ----------------------------------------------------------------------------
    @property
    def steps(self) -> int:
        """Number of time steps, totalTime / dt."""
        return round(self.totalTime / self.dt)

    @property
    def n_agents(self) -> int:
        """Glider count: the pinned agents if any, else numAgents."""
        return len(self.agents) if self.agents is not None else self.numAgents

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> Law:
        """Validate a mapping of seed parameter names (missing keys take the defaults)."""
        d = dict(data or {})
        for key, item_cls in (("thermals", PinnedThermal), ("agents", PinnedAgent)):
            items = d.get(key)
            if items is None:
                continue
            if not isinstance(items, list | tuple):
                raise ConfigError(f"{key}: expected a list of mappings, got {items!r}")
            d[key] = tuple(
                it if isinstance(it, item_cls) else from_dict(item_cls, it, path=f"{key}[{i}]")
                for i, it in enumerate(items)
            )
        return from_dict(cls, d)

    def replace(self, **changes: Any) -> Law:
        """A copy with ``changes`` applied and validated (via :meth:`from_dict`)."""
        return Law.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (lists, dicts), the inverse of :meth:`from_dict`."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            out[f.name] = _plain(getattr(self, f.name))
        return out


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value
