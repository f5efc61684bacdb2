"""Scene spec: YAML -> frozen dataclasses; a :class:`Scene` builds only the parts a scene asks for.

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

Validation is eager and cheap (unknown keys, ids, EchoParams, Law and ForestSpec are checked
when the scene is loaded); the heavy parts are built lazily and only when needed:

* the forest only if at least one sonar exists, and with ``tiled: true`` only the tiles near a
  sonar's position when an echo is requested (:meth:`Scene.leaves_near`);
* the swarm only if the scene has a ``swarm`` section;
* echo parameters per sonar, paths per vehicle.

Kinematic paths are :class:`Trajectory` objects: linear interpolation of position, bank and
airspeed, shortest-arc interpolation of heading (the same code drives ``echoloop replay``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.config import ConfigError, from_dict, load_yaml
from sim_core.flight import FlightParams
from sim_core.pose import quat_normalize, quat_slerp

__all__ = [
    "ClockSpec",
    "EarSpec",
    "ForestSceneSpec",
    "PathSpec",
    "Scene",
    "SceneSpec",
    "SonarSpec",
    "SwarmSceneSpec",
    "Trajectory",
    "TrajectoryReader",
    "VehicleSpec",
    "load_scene",
    "sample_paths",
]

FloatArray = NDArray[np.float64]


class TrajectoryReader(Protocol):
    """Reads a logged path: ``reader(path, vehicle_id=, topic=, origin=) -> Trajectory``
    (``hil_bridge.recording.logs.load_trajectory``); raises ``ValueError`` naming the file on bad
    input."""

    def __call__(
        self,
        path: str,
        *,
        vehicle_id: int | None = None,
        topic: str | None = None,
        origin: tuple[float, float, float] | None = None,
    ) -> Trajectory: ...


# --------------------------------------------------------------------------- trajectories


def _wrap_pi(a: FloatArray) -> FloatArray:
    """Angles wrapped to [-pi, pi)."""
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    """A timed kinematic path, sampled by interpolation.

    Arrays (K >= 2 samples): ``t`` (K,) s strictly increasing; ``xyz`` (K, 3) m ENU; ``heading``
    (K,) rad from +x towards +y; ``bank`` (K,) rad; ``airspeed`` (K,) m/s. ``loop``: times past
    the end wrap around to the start (otherwise they clamp to the last sample). ``quat``
    (K, 4), optional: the logged attitude, world-from-body ``[w, x, y, z]`` (ENU/FLU,
    :mod:`sim_core.pose`), sampled by :meth:`attitude`.
    """

    t: FloatArray
    xyz: FloatArray
    heading: FloatArray
    bank: FloatArray
    airspeed: FloatArray
    loop: bool = False
    quat: FloatArray | None = None
    _table: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        k = t.shape[0] if t.ndim == 1 else -1
        if k < 2:
            raise ValueError(f"t: expected a 1-D array of at least 2 times, got shape {t.shape}")
        shapes = {"xyz": (k, 3), "heading": (k,), "bank": (k,), "airspeed": (k,)}
        if self.quat is not None:
            shapes["quat"] = (k, 4)
        arrays = {"t": t}
        for name, shape in shapes.items():
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
            arrays[name] = arr
        for name, arr in arrays.items():
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name}: contains non-finite values")
            object.__setattr__(self, name, arr)
        if self.quat is not None:
            object.__setattr__(self, "quat", quat_normalize(arrays["quat"]))
        if not np.all(np.diff(t) > 0):
            bad = int(np.argmin(np.diff(t) > 0)) + 1
            raise ValueError(f"t: expected strictly increasing times, t[{bad}] = {t[bad]}")
        object.__setattr__(self, "_table", np.column_stack([
            arrays["xyz"], np.unwrap(arrays["heading"]), arrays["bank"], arrays["airspeed"]]))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def sample(self, t: float | FloatArray) -> dict[str, FloatArray]:
        """Interpolated state at time(s) ``t`` (s, shape (Q,) or scalar).

        Returns arrays shaped like ``t``: ``x, y, z, heading`` (wrapped to [-pi, pi)),
        ``bank, airspeed`` and ``vz`` (m/s, the slope of z over the containing segment).
        """
        tq = np.asarray(t, dtype=np.float64)
        out = sample_paths((self,), tq.reshape(1, -1))
        return {k: v.reshape(tq.shape) for k, v in out.items()}

    def attitude(self, t: float | FloatArray) -> FloatArray | None:
        """Logged attitude at time(s) ``t``: shape ``t.shape + (4,)``, spherical interpolation
        between the neighbouring samples (times clamp or wrap as in :meth:`sample`); None when
        the trajectory carries no attitude."""
        if self.quat is None:
            return None
        tq = np.asarray(t, dtype=np.float64)
        if self.loop:
            tq = self.t[0] + np.mod(tq - self.t[0], self.duration)
        else:
            tq = np.clip(tq, self.t[0], self.t[-1])
        seg = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self) - 2)
        f = (tq - self.t[seg]) / (self.t[seg + 1] - self.t[seg])
        return quat_slerp(self.quat[seg], self.quat[seg + 1], f)

    @classmethod
    def from_path(
        cls,
        xyz: FloatArray,
        heading: FloatArray | None,
        *,
        speed_mps: float,
        loop: bool = True,
    ) -> Trajectory:
        """Time a geometric path (K, 3) at constant ``speed_mps`` (arc length / speed).

        ``heading`` None: the direction of travel of each segment (last repeats). Bank is the
        coordinated-turn bank ``atan(v * dpsi/dt / g)`` of the timed path.
        """
        p = np.asarray(xyz, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
            raise ValueError(f"xyz: expected shape (K>=2, 3), got {p.shape}")
        if not speed_mps > 0:
            raise ValueError(f"speed_mps: expected > 0, got {speed_mps}")
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-9])
        p = p[keep]
        seg = seg[seg > 1e-9]
        t = np.concatenate([[0.0], np.cumsum(seg)]) / speed_mps
        if heading is None:
            d = np.diff(p[:, :2], axis=0)
            h = np.arctan2(d[:, 1], d[:, 0])
            hdg = np.concatenate([h, h[-1:]])
        else:
            hdg = np.asarray(heading, dtype=np.float64)[keep]
        rate = np.gradient(np.unwrap(hdg), t)
        bank = np.arctan(speed_mps * rate / 9.81)
        return cls(t, p, hdg, bank, np.full(t.shape, float(speed_mps)), loop=loop)


def sample_paths(trajs: Sequence[Trajectory], t: ArrayLike) -> dict[str, FloatArray]:
    """Trajectory ``trajs[v]`` at its own times ``t[v]`` (shape (V, Q), s), all at once: the
    interpolation of :meth:`Trajectory.sample` (``np.interp``'s, value for value), arrays
    (V, Q) ``x, y, z, heading, bank, airspeed, vz``."""
    tq = np.asarray(t, dtype=np.float64)
    if tq.ndim != 2 or tq.shape[0] != len(trajs):
        raise ValueError(f"t: expected shape ({len(trajs)}, Q), got {tq.shape}")
    lo, hi, t0, t1, tv = [], [], [], [], []
    for traj, times in zip(trajs, tq, strict=True):
        if traj.loop:
            times = traj.t[0] + np.mod(times - traj.t[0], traj.duration)
        else:
            times = np.clip(times, traj.t[0], traj.t[-1])
        j = np.clip(np.searchsorted(traj.t, times, side="right") - 1, 0, len(traj) - 2)
        lo.append(traj._table[j])
        hi.append(traj._table[j + 1])
        t0.append(traj.t[j])
        t1.append(traj.t[j + 1])
        tv.append(times)
    a, b = np.stack(lo), np.stack(hi)  # (V, Q, 6)
    ta, tb, x = np.stack(t0), np.stack(t1), np.stack(tv)
    slope = (b - a) / (tb - ta)[..., None]
    val = np.where((x == tb)[..., None], b, slope * (x - ta)[..., None] + a)
    return {
        "x": val[..., 0], "y": val[..., 1], "z": val[..., 2], "heading": _wrap_pi(val[..., 3]),
        "bank": val[..., 4], "airspeed": val[..., 5], "vz": slope[..., 2],
    }


def _densify(points: FloatArray, max_step_m: float) -> FloatArray:
    """Polyline (K, 3) resampled so no segment is longer than ``max_step_m`` (corners kept)."""
    out = [points[:1]]
    for a, b in itertools.pairwise(points):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / max_step_m))
        f = np.arange(1, n + 1, dtype=np.float64)[:, None] / n
        out.append(a + (b - a) * f)
    return np.concatenate(out)


# --------------------------------------------------------------------------- spec dataclasses


@dataclass(frozen=True, slots=True)
class ClockSpec:
    """How the server paces sim time.

    ``mode``: ``realtime`` (paced to the wall clock times ``rate``), ``lockstep`` (each step
    waits for the registered autopilots' commands and sonar heads' pings it needs, at most
    ``lockstep_timeout_s`` of wall time per step, ``lockstep_start_timeout_s`` for a participant
    not heard from yet; a miss is a stall and the step goes ahead), ``fast`` (as fast as
    possible). A participant that stalls ``lockstep_max_stalls`` steps in a row is no longer
    waited for until it answers again (``hil_bridge.server.lockstep``).
    """

    mode: Literal["realtime", "lockstep", "fast"] = "realtime"
    rate: float = 1.0
    lockstep_timeout_s: float = 1.0
    lockstep_max_stalls: int = 10
    lockstep_start_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise ValueError(f"rate: expected a real-time factor > 0, got {self.rate}")
        if not self.lockstep_timeout_s > 0:
            raise ValueError(f"lockstep_timeout_s: expected > 0, got {self.lockstep_timeout_s}")
        if not self.lockstep_start_timeout_s > 0:
            raise ValueError("lockstep_start_timeout_s: expected > 0, got "
                             f"{self.lockstep_start_timeout_s}")
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
    (vehicle of a multi-vehicle log), ``topic`` (ROS 2 bags; DataFlash: ``POS``, ``GPS[1]``...)
    and ``origin`` ([lat, lon, alt] of the local ENU frame for geodetic logs; default the first
    fix); ``points`` is a list of
    [x, y, z] flown at ``speed_mps``. ``speed_mps`` also times the figure-eight route.
    """

    kind: Literal["figure_eight", "file", "points"]
    speed_mps: float = 5.0
    params: dict[str, Any] = field(default_factory=dict)
    file: str | None = None
    id: int | None = None
    topic: str | None = None
    origin: tuple[float, float, float] | None = None
    points: tuple[tuple[float, float, float], ...] = ()
    loop: bool = True

    def __post_init__(self) -> None:
        if not self.speed_mps > 0:
            raise ValueError(f"speed_mps: expected > 0, got {self.speed_mps}")
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

    def __post_init__(self) -> None:
        if self.id < 0:
            raise ValueError(f"id: expected >= 0, got {self.id}")
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


def load_scene(
    source: str | Path | Mapping[str, Any] | SceneSpec,
    *,
    trajectory_reader: TrajectoryReader | None = None,
) -> Scene:
    """Build a :class:`Scene` from a YAML path, a mapping or a :class:`SceneSpec` (validated).

    ``trajectory_reader`` reads the ``kind: file`` paths (see :class:`Scene`).
    """
    if isinstance(source, SceneSpec):
        return Scene(source, trajectory_reader=trajectory_reader)
    data = source if isinstance(source, Mapping) else load_yaml(source)
    where = "scene" if isinstance(source, Mapping) else str(source)
    try:
        return Scene(from_dict(SceneSpec, data, path="scene" if where == "scene" else ""),
                     trajectory_reader=trajectory_reader)
    except ConfigError as exc:
        if where == "scene":
            raise
        raise ConfigError(f"{where}: {exc}") from None


# --------------------------------------------------------------------------- runtime scene


class Scene:
    """A validated scene whose heavy parts are built on first use, and only if needed.

    Attributes built lazily (check :attr:`built` to see which exist): ``forest_source``
    (None without sonars), ``swarm`` (None without a swarm section). Glider ids of the swarm are
    ``swarm.first_id + i``; they must not collide with vehicle ids (checked here).

    Files are I/O, which ``sim_core`` does not do: a scene with ``kind: file`` paths needs a
    ``trajectory_reader`` (the layer that runs the scene passes
    ``hil_bridge.recording.logs.load_trajectory``).
    """

    def __init__(
        self, spec: SceneSpec, *, trajectory_reader: TrajectoryReader | None = None
    ) -> None:
        self.spec = spec
        self.trajectory_reader = trajectory_reader
        self.built: set[str] = set()
        self._echo_params: dict[int, Any] = {}
        self._validate_parts()

    # ---- validation of the sub-specs owned by other packages (cheap, eager)

    def _validate_parts(self) -> None:
        spec = self.spec
        if spec.forest is not None and spec.sonars:
            self._forest_spec()
        for i, s in enumerate(spec.sonars):
            try:
                self._echo_params[s.id] = self._make_echo_params(s)
            except ValueError as exc:
                raise ConfigError(f"sonars[{i}].echo: {exc}") from None
            from sim_core.sonar import FIDELITIES

            if s.fidelity not in FIDELITIES:
                raise ConfigError(
                    f"sonars[{i}].fidelity: expected one of {sorted(FIDELITIES)}, "
                    f"got {s.fidelity!r}"
                )
        glider_ids = self.glider_ids
        clash = sorted(set(glider_ids) & {v.id for v in spec.vehicles})
        if clash:
            raise ConfigError(f"vehicles: id(s) {clash} collide with swarm glider ids")
        mounts = set(glider_ids) | {v.id for v in spec.vehicles}
        for i, s in enumerate(spec.sonars):
            if s.mount not in mounts:
                raise ConfigError(
                    f"sonars[{i}].mount: no vehicle or glider with id {s.mount}; "
                    f"ids are {sorted(mounts)}"
                )
        for i, v in enumerate(spec.vehicles):
            if v.path.kind in ("file", "figure_eight"):
                try:
                    self._vehicle_trajectory(v)
                except ValueError as exc:
                    raise ConfigError(f"vehicles[{i}].path: {exc}") from None

    def _forest_spec(self) -> Any:
        from sim_core.world import ForestSpec
        from sim_core.world.presets import get_preset

        f = self.spec.forest
        if f is None:
            return None
        if f.preset is not None:
            try:
                return get_preset(f.preset)
            except (KeyError, ValueError) as exc:
                raise ConfigError(f"forest.preset: {exc}") from None
        return from_dict(ForestSpec, f.spec, path="forest.spec")

    @staticmethod
    def _make_echo_params(sonar: SonarSpec) -> Any:
        from sim_core.sonar import EchoParams

        return from_dict(EchoParams, sonar.echo, path=f"sonars[{sonar.id}].echo")

    # ---- ids and lookups

    @property
    def glider_ids(self) -> tuple[int, ...]:
        """Ids of the swarm's gliders (empty without a swarm)."""
        if self.spec.swarm is None:
            return ()
        first = self.spec.swarm.first_id
        return tuple(first + i for i in range(int(self.law.n_agents)))

    @property
    def vehicle_ids(self) -> tuple[int, ...]:
        return tuple(v.id for v in self.spec.vehicles)

    def sonar(self, sonar_id: int) -> SonarSpec:
        for s in self.spec.sonars:
            if s.id == sonar_id:
                return s
        raise KeyError(sonar_id)

    def echo_params(self, sonar_id: int) -> Any:
        """The validated :class:`sim_core.sonar.EchoParams` of sonar ``sonar_id``."""
        return self._echo_params[sonar_id]

    # ---- lazily built parts

    @cached_property
    def law(self) -> Any:
        """The swarm's :class:`sim_core.soaring.Law` (``default`` = the seed 002 law)."""
        if self.spec.swarm is None:
            raise ValueError("scene has no swarm section")
        from sim_core.soaring import Law

        sw = self.spec.swarm
        try:
            return Law.from_yaml(sw.law, overrides=dict(sw.overrides))
        except (ValueError, OSError) as exc:
            raise ConfigError(f"swarm.law: {exc}") from None

    @cached_property
    def swarm(self) -> Any:
        """The swarm flown in continuous time, a :class:`sim_core.soaring.continuous.
        ContinuousSwarm` (batch 1: the law's controller every ``law.dt``, the gliders flown
        by :mod:`sim_core.flight` with ``swarm.flight``), or None without a swarm section."""
        if self.spec.swarm is None:
            return None
        from sim_core.soaring.continuous import ContinuousSwarm

        self.built.add("swarm")
        sw = self.spec.swarm
        return ContinuousSwarm(self.law, seed=self.spec.seed if sw.seed is None else sw.seed,
                               flight=sw.flight)

    @cached_property
    def forest_source(self) -> Any:
        """TiledForest (tiled) or the one-shot forest's Leaves; None when no sonar needs it."""
        f = self.spec.forest
        if f is None or not self.spec.sonars:
            return None
        forest_spec = self._forest_spec()
        seed = self.spec.seed if f.seed is None else f.seed
        if f.tiled:
            from sim_core.world import TiledForest

            self.built.add("forest_tiles")
            return TiledForest(
                forest_spec, seed=seed, tile_size_m=f.tile_size_m,
                max_cache_bytes=f.max_cache_bytes,
            )
        from sim_core.world import build_forest

        self.built.add("forest")
        return build_forest(forest_spec, seed=seed).leaves

    def echo_range_m(self, sonar_id: int) -> float:
        """Farthest range sonar ``sonar_id``'s echo window holds: ``samples / fs * c / 2`` m."""
        p = self._echo_params[sonar_id]
        return float(p.samples / p.fs * p.sound_speed / 2.0)

    def query_radius_m(self, sonar_id: int) -> float:
        """Radius of the leaves gathered for an echo of ``sonar_id``: ``forest.query_radius_m``,
        capped just inside the echo window (the synthesiser rejects leaves beyond it)."""
        f = self.spec.forest
        if f is None:
            raise ValueError("scene has no forest")
        return min(f.query_radius_m, 0.999 * self.echo_range_m(sonar_id))

    def leaves_near(self, point: FloatArray, radius_m: float | None = None) -> Any:
        """Leaves within ``radius_m`` (default ``forest.query_radius_m``) of ``point`` (3,) m."""
        src = self.forest_source
        if src is None:
            raise ValueError("scene has no forest for a sonar (no 'forest' or no 'sonars')")
        f = self.spec.forest
        r = float(radius_m if radius_m is not None else f.query_radius_m)  # type: ignore[union-attr]
        p = np.asarray(point, dtype=np.float64).reshape(3)
        if f.tiled:  # type: ignore[union-attr]
            return src.leaves_near(p, r)
        return src.select(src.query_ball(p, r))

    def _vehicle_trajectory(self, v: VehicleSpec) -> Trajectory:
        ps = v.path
        if ps.kind == "file":
            if self.trajectory_reader is None:
                raise ValueError(
                    f"file {ps.file!r}: a logged path needs a trajectory reader; build the "
                    "scene with trajectory_reader=hil_bridge.recording.logs.load_trajectory"
                )
            traj = self.trajectory_reader(str(ps.file), vehicle_id=ps.id, topic=ps.topic,
                                          origin=ps.origin)
            if ps.loop:
                traj = dataclasses.replace(traj, loop=True)
        elif ps.kind == "points":
            pts = np.asarray(ps.points, dtype=np.float64)
            if ps.loop and not np.array_equal(pts[0], pts[-1]):
                pts = np.concatenate([pts, pts[:1]])
            traj = Trajectory.from_path(
                _densify(pts, 0.5), None, speed_mps=ps.speed_mps, loop=ps.loop
            )
        else:
            from sim_core.sonar.scenarios import figure_eight_path

            try:
                xyz, heading = figure_eight_path(**ps.params)
            except TypeError as exc:
                raise ValueError(f"params: {exc}") from None
            if ps.loop:
                xyz = np.concatenate([xyz, xyz[:1]])
                heading = np.concatenate([heading, heading[:1]])
            traj = Trajectory.from_path(xyz, heading, speed_mps=ps.speed_mps, loop=ps.loop)
        if v.z_m is not None:
            xyz = traj.xyz.copy()
            xyz[:, 2] = v.z_m
            traj = dataclasses.replace(traj, xyz=xyz)
        if v.time_offset_s:
            traj = dataclasses.replace(traj, t=traj.t + v.time_offset_s)
        return traj

    @cached_property
    def trajectories(self) -> dict[int, Trajectory]:
        """Vehicle id -> its :class:`Trajectory` (built on first access)."""
        self.built.add("trajectories")
        return {v.id: self._vehicle_trajectory(v) for v in self.spec.vehicles}

