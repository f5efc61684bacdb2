"""One echo of the simulation server's echo service, and computing it: what goes in (an
:class:`EchoRequest`: the ping and its sonar's :class:`SonarPose` at emission; the plain-data
:class:`EchoJob` a worker gets), what comes out (:class:`EchoResult`) and the pure functions of
the scene that compute it, shared by the scheduler (:mod:`hil_bridge.server.echo_service`) and
its workers (:mod:`hil_bridge.server.echo_pool`).

:func:`compute_echo` is the whole computation: the ping's beam at the sonar's world pose
(:func:`sim_core.sonar.mount.ping_beam`: az/el in the sonar frame, so the beam rolls and
pitches with the vehicle), the sonar's ears turned the same way, the leaves around the sonar
and :func:`sim_core.sonar.synthesize`. :func:`answer_echo` computes it within a deadline,
planned by a :class:`DeadlinePlanner` (degraded to ``realtime`` or dropped when the scene's
fidelity does not fit); what synthesises the echo is a :data:`Synthesize` it may be given (the
seam through which a test makes an echo take a known time). :func:`compute_points` gathers the
leaves of ``/forest/points``.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.bus.messages import SonarPing
from hil_bridge.errors import HilError
from sim_core.scene import Scene
from sim_core.sonar.cost import COST, EchoCost

__all__ = [
    "MAX_POINT_TILES",
    "PUBLISH_MARGIN_S",
    "DeadlinePlanner",
    "EchoJob",
    "EchoRequest",
    "EchoResult",
    "Region",
    "SonarPose",
    "Synthesize",
    "answer_echo",
    "compute_echo",
    "compute_points",
    "region_tiles",
]

F8 = NDArray[np.float64]
#: a ball of the world: (centre (x, y, z) m, radius m)
Region = tuple[tuple[float, float, float], float]
#: tiles built for ``/forest/points`` at most (the route from its start)
MAX_POINT_TILES = 64
#: time kept free after an echo for publishing it (s)
PUBLISH_MARGIN_S = 1e-3
#: echoes a deadline planner gives up in a row before it tries one on the cost model alone
PROBE_AFTER = 4
#: ``synthesize(leaves, beam, params, fidelity=name) -> echo``: the signature of
#: :func:`sim_core.sonar.synthesize`, which computes an echo unless another is given
Synthesize = Callable[..., Any]


@dataclass(frozen=True, slots=True)
class SonarPose:
    """Where a sonar is at ``t_ns`` (sim ns): ``position`` (3,) m world ENU, ``orientation``
    (4,) world-from-sonar ``[w, x, y, z]``, and how fast it moves: ``velocity`` (3,) m/s world
    (None: unknown)."""

    t_ns: int
    position: F8
    orientation: F8
    velocity: F8 | None = None


@dataclass(frozen=True, slots=True)
class EchoRequest:
    """One ping to answer: its sonar, the ping, the sonar's pose at emission, the
    ``time.monotonic()`` of its arrival (for the ping → echo latency) and the deadline by
    which its echo is useful (``time.monotonic()``; None: estimated, or none)."""

    sonar_id: int
    ping: SonarPing
    pose: SonarPose
    received: float
    deadline: float | None = None


@dataclass(frozen=True, slots=True)
class EchoJob:
    """What a worker computes (plain data): the echo of ``sonar_id`` pinging ``az``, ``el``,
    ``beamwidth`` (rad, sonar frame) from ``position`` (3,) with ``orientation`` (4,), by
    ``deadline`` (``time.monotonic()``, None: at the scene's fidelity whatever it takes);
    ``velocity`` (3,) m/s world: the sonar's, for an echo model with ``doppler`` (None: the
    model's own ``platform_velocity``)."""

    sonar_id: int
    position: F8
    orientation: F8
    az: float
    el: float
    beamwidth: float
    deadline: float | None = None
    velocity: F8 | None = None


@dataclass(frozen=True, slots=True)
class EchoResult:
    """An echo: ``samples`` float32 (n,) or (channels, n) at ``fs`` Hz, what the synthesiser
    reports, the beam's world ``boresight`` (3,), the compute time, ns, and the leaves that were
    in range. ``degraded``: computed with ``realtime`` under a deadline's budget instead of the
    scene's fidelity."""

    samples: NDArray[np.float32]
    fs: float
    leaves_in_beam: int
    fidelity: str
    dropped: int
    error_bound: float
    boresight: F8
    compute_ns: int
    in_range: int = 0
    degraded: bool = False


def compute_echo(
    scene: Scene, sonar_id: int, position: F8, orientation: F8, az: float, el: float,
    beamwidth: float,
) -> EchoResult:
    """The echo of sonar ``sonar_id`` pinging at ``az``, ``el`` (rad, sonar frame) with
    ``beamwidth`` (rad) from ``position`` (3,) m and world-from-sonar ``orientation`` (4,),
    at the sonar's fidelity."""
    result = answer_echo(scene, EchoJob(sonar_id, position, orientation, az, el, beamwidth))
    if result is None:  # pragma: no cover - no deadline, never dropped
        raise HilError("an echo without a deadline was dropped")
    return result


class DeadlinePlanner:
    """Decides, for an echo with a deadline, between the scene's fidelity, ``realtime`` within
    the time left, or nothing. Its prediction is the cost model (``fast``; a ``realtime``
    sonar's own budget) times the ratio of measured to predicted times of this worker's last
    32 echoes of that fidelity (machine speed and load, this scene's leaves; 1 until known).

    A ratio is only measured on echoes computed, so one slow echo (the first of a process,
    cold) could stop every later one: after :data:`PROBE_AFTER` echoes in a row it gave up
    (:meth:`refused`), it plans the next with the cost model alone, and what that echo measures
    joins the ratios."""

    def __init__(self, cost: EchoCost = COST) -> None:
        self.cost = cost
        self._ratios: dict[str, deque[float]] = {}
        self._refused = 0

    def scale(self, fidelity: str) -> float:
        ratios = self._ratios.get(fidelity)
        return float(statistics.median(ratios)) if ratios and not self.probing else 1.0

    @property
    def probing(self) -> bool:
        """Whether the next echo is planned with the cost model alone (class docstring)."""
        return self._refused >= PROBE_AFTER

    def budget_scale(self) -> float:
        """Measured / planned time of ``realtime`` echoes (else of ``fast``: the same model)."""
        for name in ("realtime", "fast"):
            if self._ratios.get(name):
                return self.scale(name)
        return 1.0

    def refused(self) -> None:
        """An echo was given up: its predicted time did not fit before its deadline."""
        self._refused += 1

    def observe(self, fidelity: str, predicted_s: float, measured_s: float) -> None:
        self._refused = 0
        if predicted_s > 0 and measured_s > 0:
            self._ratios.setdefault(fidelity, deque(maxlen=32)).append(measured_s / predicted_s)


def answer_echo(
    scene: Scene, job: EchoJob, planner: DeadlinePlanner | None = None, *,
    synthesize: Synthesize | None = None,
) -> EchoResult | None:
    """The echo of ``job`` (see :func:`compute_echo`), within its deadline: at the sonar's
    fidelity if the predicted time fits, else degraded to ``realtime`` (without Doppler) with
    the time left as its budget, else None (the time is up). An echo model with ``doppler``
    is given the job's ``velocity`` as its ``platform_velocity``. ``synthesize``: what
    computes the echo (None: :func:`sim_core.sonar.synthesize`); the planner measures its
    time. ValueError when the scene refuses the ping."""
    if synthesize is None:
        from sim_core.sonar import synthesize as default_synthesize

        synthesize = default_synthesize
    from sim_core.sonar.model import precull_half_angle
    from sim_core.sonar.mount import ears_for_ping, ping_beam

    t0 = time.monotonic()
    if job.deadline is not None and t0 >= job.deadline - PUBLISH_MARGIN_S:
        return None
    p = np.asarray(job.position, dtype=np.float64)
    q = np.asarray(job.orientation, dtype=np.float64)
    beam = ping_beam(p, q, job.az, job.el, job.beamwidth)
    params = scene.echo_params(job.sonar_id)
    if params.doppler and job.velocity is not None:
        v = np.asarray(job.velocity, dtype=np.float64)
        params = dataclasses.replace(params, platform_velocity=(float(v[0]), float(v[1]),
                                                                float(v[2])))
    sonar = scene.sonar(job.sonar_id)
    if sonar.ears:
        ears = ears_for_ping(beam, q, [e.position_m for e in sonar.ears],
                             [e.axis for e in sonar.ears], [e.beamwidth_rad for e in sonar.ears])
        params = dataclasses.replace(params, ears=ears)
    leaves = scene.leaves_near(p, scene.query_radius_m(job.sonar_id))
    fidelity: str = sonar.fidelity
    predicted = 0.0
    if planner is not None:
        predicted = (params.budget_s if fidelity == "realtime" else
                     planner.cost.estimate(len(leaves), precull_half_angle(beam, params)))
    if job.deadline is not None and planner is not None:
        left = job.deadline - PUBLISH_MARGIN_S - time.monotonic()
        if predicted * planner.scale(fidelity) > left:
            scale = planner.budget_scale()
            budget = left / scale
            if budget <= planner.cost.overhead_s * params.channels:
                planner.refused()
                return None
            fidelity, predicted = "realtime", budget
            # Doppler is the reference fidelity's only: a degraded echo goes without
            params = dataclasses.replace(params, budget_s=budget, doppler=False)
    t1 = time.monotonic()
    echo = synthesize(leaves, beam, params, fidelity=fidelity)
    t2 = time.monotonic()
    degraded = fidelity != sonar.fidelity or params.budget_s != scene.echo_params(
        job.sonar_id).budget_s
    if planner is not None and predicted > 0:
        planner.observe(fidelity, predicted, t2 - t1)
    bound = echo.error_bound
    return EchoResult(
        samples=np.asarray(echo.samples, dtype=np.float32), fs=float(echo.fs),
        leaves_in_beam=int(echo.leaves_in_beam), fidelity=str(echo.fidelity),
        dropped=int(echo.dropped), error_bound=math.nan if bound is None else float(bound),
        boresight=np.asarray(beam.boresight, dtype=np.float64),
        compute_ns=int((t2 - t0) * 1e9), in_range=len(leaves), degraded=degraded,
    )


def region_tiles(
    forest: Any, regions: Sequence[Region], limit: int | None = None
) -> list[tuple[int, int]]:
    """Tiles of the tiled ``forest`` (a :class:`sim_core.world.TiledForest`, its geometry is
    enough) near ``regions``, in the order of the regions, at most ``limit``."""
    out: dict[tuple[int, int], None] = {}
    for center, r in regions:
        for t in forest.tiles_near(np.asarray(center, dtype=np.float64), r):
            out.setdefault(t)
            if limit is not None and len(out) >= limit:
                return list(out)
    return list(out)


def compute_points(
    scene: Scene, regions: Sequence[Region], limit: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Leaf centres (N, 3) and radii (N,) around the (centre, radius m) ``regions`` (for a
    tiled forest: every leaf of the tiles near them, at most :data:`MAX_POINT_TILES` tiles
    taken in the order of the regions), evenly decimated to at most ``limit`` (what the server
    publishes on ``/forest/points``)."""
    centers, radii = [], []
    if scene.spec.forest is not None and scene.spec.forest.tiled:
        forest = scene.forest_source
        for t in region_tiles(forest, regions, MAX_POINT_TILES):
            leaves = forest.tile(t)
            centers.append(np.asarray(leaves.centers, dtype=np.float32))
            radii.append(np.asarray(leaves.radii, dtype=np.float32))
    else:
        src = scene.forest_source
        idx = [src.query_ball(np.asarray(center, dtype=np.float64), r) for center, r in regions]
        keep = np.unique(np.concatenate(idx)) if idx else np.zeros(0, dtype=np.intp)
        centers.append(np.asarray(src.centers[keep], dtype=np.float32))
        radii.append(np.asarray(src.radii[keep], dtype=np.float32))
    c = np.concatenate(centers) if centers else np.zeros((0, 3), np.float32)
    rr = np.concatenate(radii) if radii else np.zeros(0, np.float32)
    if len(c) > limit:
        keep = np.linspace(0, len(c) - 1, limit).astype(np.intp)
        c, rr = c[keep], rr[keep]
    return c, rr

