"""The runtime scene: a validated :class:`~sim_core.scene.spec.SceneSpec` whose heavy parts are
built on first use, and the readers it is given for the files it names.

Validation is eager and cheap (unknown keys, ids, EchoParams, Law and ForestSpec are checked
when the scene is built); the heavy parts are built lazily and only when needed:

* the forest only if at least one sonar exists, and with ``tiled: true`` only the tiles near a
  sonar's position when an echo is requested (:meth:`Scene.leaves_near`);
* the swarm only if the scene has a ``swarm`` section;
* echo parameters per sonar, paths per vehicle.

Kinematic paths are :class:`sim_core.trajectory.Trajectory` objects (the same code drives
``echoloop replay``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping
from functools import cached_property
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from sim_core.config import ConfigError, from_dict
from sim_core.scene.spec import SceneSpec, SonarSpec, VehicleSpec
from sim_core.trajectory import Trajectory

if TYPE_CHECKING:
    from sim_core.soaring.law import Law
    from sim_core.world.spec import ForestFiles, ForestSpec

__all__ = ["ForestReader", "LawReader", "Scene", "TrajectoryReader"]

FloatArray = NDArray[np.float64]


class TrajectoryReader(Protocol):
    """Reads a logged path: ``reader(path, vehicle_id=, topic=, origin=, max_speed_mps=,
    segment=) -> Trajectory``
    (``hil_bridge.recording.logs.load_trajectory``); raises ``ValueError`` naming the file on bad
    input."""

    def __call__(
        self,
        path: str,
        *,
        vehicle_id: int | None = None,
        topic: str | None = None,
        origin: tuple[float, float, float] | None = None,
        max_speed_mps: float = 150.0,
        segment: int | None = None,
    ) -> Trajectory: ...


class LawReader(Protocol):
    """Reads a swarm's law: ``reader(law, overrides) -> Law``, ``law`` ``"default"`` (the
    packaged seed law) or a law file (``hil_bridge.files.soaring.load_law``); raises
    ``ValueError`` naming the file on bad input."""

    def __call__(self, path: str, overrides: Mapping[str, Any] | None = None) -> Law: ...


class ForestReader(Protocol):
    """Reads the files a forest names: ``reader(spec) -> ForestFiles``
    (``hil_bridge.files.world.load_forest_files``); raises ``ValueError`` naming the file."""

    def __call__(self, spec: ForestSpec) -> ForestFiles: ...


def _densify(points: FloatArray, max_step_m: float) -> FloatArray:
    """Polyline (K, 3) resampled so no segment is longer than ``max_step_m`` (corners kept)."""
    out = [points[:1]]
    for a, b in itertools.pairwise(points):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / max_step_m))
        f = np.arange(1, n + 1, dtype=np.float64)[:, None] / n
        out.append(a + (b - a) * f)
    return np.concatenate(out)


class Scene:
    """A validated scene whose heavy parts are built on first use, and only if needed.

    Attributes built lazily (check :attr:`built` to see which exist): ``forest_source``
    (None without sonars), ``swarm`` (None without a swarm section). Glider ids of the swarm are
    ``swarm.first_id + i``; they must not collide with vehicle ids (checked here).

    Files are I/O, which ``sim_core`` does not do; the layer that runs the scene passes readers
    (``hil_bridge.files.scene.load_scene`` does): a ``trajectory_reader`` for ``kind: file``
    paths (``hil_bridge.recording.logs.load_trajectory``), a ``law_reader`` for the swarm's law
    (``hil_bridge.files.soaring.load_law``) and a ``forest_reader`` for the files a forest names
    (``hil_bridge.files.world.load_forest_files``; a forest that names none needs none).
    """

    def __init__(
        self,
        spec: SceneSpec,
        *,
        trajectory_reader: TrajectoryReader | None = None,
        law_reader: LawReader | None = None,
        forest_reader: ForestReader | None = None,
    ) -> None:
        self.spec = spec
        self.trajectory_reader = trajectory_reader
        self.law_reader = law_reader
        self.forest_reader = forest_reader
        self.built: set[str] = set()
        self._echo_params: dict[int, Any] = {}
        self._validate_parts()

    # ---- validation of the sub-specs owned by other packages (cheap, eager)

    def _validate_parts(self) -> None:
        spec = self.spec
        if spec.forest is not None and spec.sonars:
            self.forest_spec()
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
            if self._echo_params[s.id].doppler and s.fidelity != "reference":
                raise ConfigError(
                    f"sonars[{i}].echo.doppler: needs fidelity 'reference' (the only one "
                    f"with Doppler), got {s.fidelity!r}"
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

    def forest_spec(self) -> ForestSpec | None:
        """The forest's :class:`~sim_core.world.ForestSpec` (its preset, or its ``spec``
        validated); None without a forest section."""
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
    def law(self) -> Law:
        """The swarm's :class:`sim_core.soaring.Law` (``default`` = the seed 002 law), read by
        the scene's ``law_reader``."""
        if self.spec.swarm is None:
            raise ValueError("scene has no swarm section")
        sw = self.spec.swarm
        if self.law_reader is None:
            raise ConfigError(
                f"swarm.law: {sw.law!r} needs a law reader; build the scene with "
                "law_reader=hil_bridge.files.soaring.load_law"
            )
        try:
            return self.law_reader(sw.law, dict(sw.overrides))
        except (ValueError, OSError) as exc:
            raise ConfigError(f"swarm.law: {exc}") from None

    @cached_property
    def swarm(self) -> Any:
        """The swarm flown in continuous time, a :class:`sim_core.continuous_swarm.
        ContinuousSwarm` (batch 1: the law's controller every ``law.dt``, the gliders flown
        by :mod:`sim_core.flight` with ``swarm.flight``), or None without a swarm section."""
        if self.spec.swarm is None:
            return None
        from sim_core.continuous_swarm import ContinuousSwarm

        self.built.add("swarm")
        sw = self.spec.swarm
        return ContinuousSwarm(self.law, seed=self.spec.seed if sw.seed is None else sw.seed,
                               flight=sw.flight)

    @cached_property
    def forest_files(self) -> ForestFiles:
        """What the files the forest names hold, read by the scene's ``forest_reader`` (empty
        without a reader: a forest that names no file needs none)."""
        from sim_core.world import ForestFiles

        spec = self.forest_spec()
        if spec is None or self.forest_reader is None:
            return ForestFiles()
        return self.forest_reader(spec)

    @property
    def forest_seed(self) -> int:
        """The forest's seed: ``forest.seed``, else the scene's."""
        f = self.spec.forest
        return self.spec.seed if f is None or f.seed is None else f.seed

    @cached_property
    def forest_source(self) -> Any:
        """TiledForest (tiled) or the one-shot forest's Leaves; None when no sonar needs it."""
        f = self.spec.forest
        forest_spec = self.forest_spec()
        if f is None or forest_spec is None or not self.spec.sonars:
            return None
        if f.tiled:
            from sim_core.world import TiledForest

            self.built.add("forest_tiles")
            return TiledForest(
                forest_spec, seed=self.forest_seed, files=self.forest_files,
                tile_size_m=f.tile_size_m, max_cache_bytes=f.max_cache_bytes,
            )
        from sim_core.world import build_forest

        self.built.add("forest")
        return build_forest(forest_spec, seed=self.forest_seed, files=self.forest_files).leaves

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
                                          origin=ps.origin, max_speed_mps=ps.max_speed_mps,
                                          segment=ps.segment)
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
