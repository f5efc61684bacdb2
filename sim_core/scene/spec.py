"""Scene specs: a scene as plain data -> frozen dataclasses, checked field by field.

A scene is what the simulation server owns: an optional forest, sonars mounted on vehicles,
an optional thermal-soaring swarm (thermals + gliders from a seed 002 law) and vehicles that
follow kinematic paths. Example (every key optional except where noted)::

    seed: 0                      # default seed of the forest and the swarm
    state_rate_hz: 50            # state stream (and server tick) rate
    physics_rate_hz: null        # flight integration rate (>= state_rate_hz; null: the same)
    clock: {mode: realtime, rate: 1.0, lockstep_timeout_s: 1.0}
    forest:
      preset: seed000-fig5d      # or  spec: {...ForestSpec fields...}
      seed: null                 # null: the scene's seed
      tiled: true                # TiledForest (tiles built only near a sonar) or one-shot forest
      tile_size_m: 20.0
      query_radius_m: 10.5       # leaves gathered around a sonar for each echo
    sonars:
      - {id: 0, mount: 100, fidelity: fast, echo: {}}    # echo: EchoParams overrides
        # mount_offset_m: [0.2, 0, 0]  mount_rpy_rad: [0, 0.3, 0]  (sonar pose in body axes)
        # ears: [{position_m: [0, 0.015, 0], axis: [1, 0.25, 0]}, ...]  (sonar frame)
    swarm:
      law: default               # "default" (seed 002 Law_40SurvivorsExample) or a YAML path
      overrides: {numAgents: 8}
      first_id: 0                # glider ids first_id .. first_id + numAgents - 1
      flight: {}                 # sim_core.flight.FlightParams of the gliders
    vehicles:
      - id: 100
        flight: {}               # FlightParams once commanded (vertical: hold by default)
        path:                    # or {kind: file, file: run.csv, id: 3} / {kind: points, ...}
          kind: figure_eight     # sim_core.sonar.scenarios.figure_eight_path(**params)
          speed_mps: 3.0
          params: {center: [8, 7], half_length: 7, half_width: 5, altitude: 2, count: 400}
        z_m: 2.0                 # optional altitude override

The cross-checks that need other packages (EchoParams, the law, the forest spec, paths) and
the lazily built parts are :class:`sim_core.scene.Scene`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

from sim_core.flight import FlightParams
from sim_core.sixdof.model import SixDofSpec

__all__ = [
    "ClockSpec",
    "EarSpec",
    "ForestSceneSpec",
    "PathSpec",
    "SceneSpec",
    "SonarSpec",
    "SwarmSceneSpec",
    "VehicleSpec",
]


@dataclass(frozen=True, slots=True)
class ClockSpec:
    """How the server paces sim time.

    ``mode``: ``realtime`` (paced to the wall clock times ``rate``), ``lockstep`` (each step
    waits for the registered autopilots' commands and sonar heads' pings it needs, at most
    ``lockstep_timeout_s`` of wall time per step, ``lockstep_start_timeout_s`` for a participant
    not heard from yet; a miss is a stall and the step goes ahead), ``fast`` (as fast as
    possible). A participant that stalls ``lockstep_max_stalls`` steps in a row is no longer
    waited for until it answers again (``hil_bridge.server.lockstep``). ``max_speed`` holds
    ``lockstep`` and ``fast`` to at most that many sim seconds per wall second (None: as fast as
    they go; ``echoloop launch --speed``).
    """

    mode: Literal["realtime", "lockstep", "fast"] = "realtime"
    rate: float = 1.0
    lockstep_timeout_s: float = 1.0
    lockstep_max_stalls: int = 10
    lockstep_start_timeout_s: float = 10.0
    max_speed: float | None = None

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise ValueError(f"rate: expected a real-time factor > 0, got {self.rate}")
        if not self.lockstep_timeout_s > 0:
            raise ValueError(f"lockstep_timeout_s: expected > 0, got {self.lockstep_timeout_s}")
        if not self.lockstep_start_timeout_s > 0:
            raise ValueError("lockstep_start_timeout_s: expected > 0, got "
                             f"{self.lockstep_start_timeout_s}")
        if self.max_speed is not None and not self.max_speed > 0:
            raise ValueError(f"max_speed: expected sim s per wall s > 0, got {self.max_speed}")
        if self.lockstep_max_stalls < 1:
            raise ValueError(f"lockstep_max_stalls: expected >= 1, got {self.lockstep_max_stalls}")


@dataclass(frozen=True, slots=True)
class ForestSceneSpec:
    """The forest: a preset name or ForestSpec fields, built tiled (lazily) or in one shot."""

    preset: str | None = None
    spec: dict[str, Any] | None = None
    seed: int | None = None
    tiled: bool = True
    tile_size_m: float = 20.0
    max_cache_bytes: int = 256 * 2**20
    query_radius_m: float = 10.5

    def __post_init__(self) -> None:
        if (self.preset is None) == (self.spec is None):
            raise ValueError("forest: give exactly one of 'preset' (a name) or 'spec' (fields)")
        if self.seed is not None and self.seed < 0:
            raise ValueError(f"seed: expected >= 0, got {self.seed}")
        if not self.tile_size_m > 0:
            raise ValueError(f"tile_size_m: expected > 0, got {self.tile_size_m}")
        if self.max_cache_bytes <= 0:
            raise ValueError(f"max_cache_bytes: expected > 0, got {self.max_cache_bytes}")
        if not self.query_radius_m > 0:
            raise ValueError(f"query_radius_m: expected > 0, got {self.query_radius_m}")


Vec3 = tuple[float, float, float]


def _nonzero(v: Vec3, name: str) -> None:
    if not math.hypot(*v) > 0:
        raise ValueError(f"{name}: expected a non-zero vector, got {list(v)}")


@dataclass(frozen=True, slots=True)
class EarSpec:
    """One receiver of a sonar: ``position_m`` and beam ``axis`` (any length) in the sonar
    frame (x forward, y left, z up), ``beamwidth_rad`` null = the ping's."""

    position_m: Vec3 = (0.0, 0.0, 0.0)
    axis: Vec3 = (1.0, 0.0, 0.0)
    beamwidth_rad: float | None = None

    def __post_init__(self) -> None:
        _nonzero(self.axis, "axis")
        if self.beamwidth_rad is not None and not 0 < self.beamwidth_rad < math.pi:
            raise ValueError(f"beamwidth_rad: expected 0 < value < pi, got {self.beamwidth_rad}")


@dataclass(frozen=True, slots=True)
class SonarSpec:
    """A sonar mounted on vehicle ``mount``; answers ``/sonar/<id>/ping`` with an echo.

    Its pose on the vehicle: ``mount_offset_m`` (body axes FLU, m) and ``mount_rpy_rad``
    (body-from-sonar Z-Y-X roll, pitch, yaw, rad); identity by default. A ping's ``az``/``el``
    are in the sonar frame. ``ears`` (sonar frame) make a multi-channel echo, one per ear.
    ``echo``: :class:`sim_core.sonar.EchoParams` overrides; with ``doppler: true`` (fidelity
    ``reference`` only) the simulation server gives the model the sonar's velocity at each
    ping's emission as its ``platform_velocity``.
    """

    id: int
    mount: int
    fidelity: str = "fast"
    echo: dict[str, Any] = field(default_factory=dict)
    mount_offset_m: Vec3 = (0.0, 0.0, 0.0)
    mount_rpy_rad: Vec3 = (0.0, 0.0, 0.0)
    ears: tuple[EarSpec, ...] = ()

    def __post_init__(self) -> None:
        if self.id < 0:
            raise ValueError(f"id: expected >= 0, got {self.id}")
        if "ears" in self.echo:
            raise ValueError(
                "echo.ears: give the ears as the sonar's 'ears' (position_m, axis in the sonar "
                "frame), which turn with the sonar"
            )


@dataclass(frozen=True, slots=True)
class SwarmSceneSpec:
    """Thermals + gliders from a seed 002 law (``default`` or a YAML path) and overrides."""

    law: str = "default"
    overrides: dict[str, Any] = field(default_factory=dict)
    seed: int | None = None
    first_id: int = 0
    flight: FlightParams = field(default_factory=FlightParams)

    def __post_init__(self) -> None:
        if self.seed is not None and self.seed < 0:
            raise ValueError(f"seed: expected >= 0, got {self.seed}")
        if self.first_id < 0:
            raise ValueError(f"first_id: expected >= 0, got {self.first_id}")
        if self.flight.vertical == "hold":
            raise ValueError("flight.vertical: swarm gliders glide on the law's polar, got 'hold'")


@dataclass(frozen=True, slots=True)
class PathSpec:
    """A kinematic path: ``figure_eight`` (seed 000 "8" route), a logged ``file``, or points.

    ``params`` go to :func:`sim_core.sonar.scenarios.figure_eight_path`; ``file`` names a flight
    log read by the scene's :data:`TrajectoryReader`
    (``hil_bridge.recording.logs.load_trajectory``: CSV,
    NPZ, ULog, DataFlash, tlog, ROS 2 bags, echoloop recordings) with its options ``id``
    (vehicle of a multi-vehicle log), ``topic`` (the position source by name: a ROS 2 bag's
    topic; ULog ``vehicle_gps_position``...; tlog ``LOCAL_POSITION_NED``...; DataFlash ``POS``,
    ``GPS[1]``...), ``origin`` ([lat, lon, alt] of the local ENU frame for geodetic logs; default
    the first fix), ``max_speed_mps`` (a step implying a faster speed is a position jump: the
    log is split there, never flown through) and ``segment`` (the piece between jumps to fly,
    0-based; default the longest); ``points`` is a list of [x, y, z] flown at ``speed_mps``.
    ``speed_mps`` also times the figure-eight route.
    """

    kind: Literal["figure_eight", "file", "points"]
    speed_mps: float = 5.0
    params: dict[str, Any] = field(default_factory=dict)
    file: str | None = None
    id: int | None = None
    topic: str | None = None
    origin: tuple[float, float, float] | None = None
    max_speed_mps: float = 150.0
    segment: int | None = None
    points: tuple[tuple[float, float, float], ...] = ()
    loop: bool = True

    def __post_init__(self) -> None:
        if not self.speed_mps > 0:
            raise ValueError(f"speed_mps: expected > 0, got {self.speed_mps}")
        if not self.max_speed_mps > 0:
            raise ValueError(f"max_speed_mps: expected > 0, got {self.max_speed_mps}")
        if self.segment is not None and self.segment < 0:
            raise ValueError(f"segment: expected >= 0, got {self.segment}")
        if self.kind == "file" and not self.file:
            raise ValueError("file: required when kind is 'file'")
        if self.kind == "points" and len(self.points) < 2:
            raise ValueError("points: expected at least 2 [x, y, z] points for kind 'points'")


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    """A vehicle following a kinematic path; its state is published as ``/glider/<id>/state``.

    ``commanded: true``: once an autopilot's first valid ``/glider/<id>/cmd`` arrives the vehicle
    leaves its path and flies :mod:`sim_core.flight` (coordinated turns, the bank and airspeed
    responses of ``flight``; ``flight.vertical`` ``hold`` by default: a powered vehicle keeping
    its height) on the held command, clipped to ``|bank| <= bank_max_rad`` and
    ``speed_min_mps..speed_max_mps``.

    ``sixdof``: the vehicle is a 6-DoF JSBSim aircraft (:class:`sim_core.sixdof.SixDofSpec`)
    from the start, at its path's first point and heading, flown on control surfaces
    (``/glider/<id>/surfaces``) in the scene's updraft; its path only places it.
    """

    id: int
    path: PathSpec
    z_m: float | None = None
    time_offset_s: float = 0.0
    commanded: bool = False
    bank_max_rad: float = 0.5236
    speed_min_mps: float = 1.0
    speed_max_mps: float = 20.0
    flight: FlightParams = field(default_factory=FlightParams)
    sixdof: SixDofSpec | None = None

    def __post_init__(self) -> None:
        if self.id < 0:
            raise ValueError(f"id: expected >= 0, got {self.id}")
        if self.sixdof is not None and self.commanded:
            raise ValueError("commanded, sixdof: a 6-DoF vehicle flies on control surfaces, "
                             "not on bank and airspeed commands: expected one of them")
        if not 0 < self.bank_max_rad < math.pi / 2:
            raise ValueError(f"bank_max_rad: expected 0 < value < pi/2, got {self.bank_max_rad}")
        if not 0 < self.speed_min_mps <= self.speed_max_mps:
            raise ValueError(
                "speed_min_mps, speed_max_mps: expected 0 < min <= max, got "
                f"{self.speed_min_mps}, {self.speed_max_mps}"
            )

    @property
    def glides(self) -> bool:
        """Whether the vehicle, once commanded, glides on the SB-XC polar (else holds height)."""
        return self.flight.vertical == "glide"


@dataclass(frozen=True, slots=True)
class SceneSpec:
    """A whole scene (see the module docstring)."""

    seed: int = 0
    state_rate_hz: float = 50.0
    physics_rate_hz: float | None = None
    clock: ClockSpec = field(default_factory=ClockSpec)
    forest: ForestSceneSpec | None = None
    sonars: tuple[SonarSpec, ...] = ()
    swarm: SwarmSceneSpec | None = None
    vehicles: tuple[VehicleSpec, ...] = ()

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"seed: expected >= 0, got {self.seed}")
        if not 0 < self.state_rate_hz <= 2000:
            raise ValueError(f"state_rate_hz: expected 0 < rate <= 2000, got {self.state_rate_hz}")
        if self.physics_rate_hz is not None and not (
            self.state_rate_hz <= self.physics_rate_hz <= 100_000
        ):
            raise ValueError(
                f"physics_rate_hz: expected state_rate_hz ({self.state_rate_hz}) <= rate <= "
                f"100000 or null, got {self.physics_rate_hz}"
            )
        vids = [v.id for v in self.vehicles]
        dup = sorted({i for i in vids if vids.count(i) > 1})
        if dup:
            raise ValueError(f"vehicles: duplicate id(s) {dup}")
        sids = [s.id for s in self.sonars]
        dup = sorted({i for i in sids if sids.count(i) > 1})
        if dup:
            raise ValueError(f"sonars: duplicate id(s) {dup}")
        if self.sonars and self.forest is None:
            raise ValueError("sonars: a sonar needs a 'forest' section to echo from")
