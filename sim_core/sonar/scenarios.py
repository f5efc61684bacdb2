"""The seed 000 sonar scenarios as plain scene builders (no timing, no I/O).

* Fig 6 — :func:`fig6_scene`: a static sonar at (2, 6, 15) m aimed at the centre of one maple's
  leaf bounding box, beamwidth 10/30/50 deg.
* Fig 7 — :func:`figure_eight_path` and :func:`fig7_scene`: 12 pings along an "8" route around
  the canopies of the Fig 5(d) forest (4 maples + 1 hazelnut bush), each aimed at the nearest
  canopy with a beamwidth drawn from U[30, 65] deg.
* Table 1 — :func:`table1_setups`: a cluster of 1-5 maples; setup I a circular path (1/5/10/15
  positions, beamwidth 10 deg, aimed at the cluster's canopy centre), setup II a fixed position
  with beamwidth 10..50 deg. Published MATLAB timings: :data:`TABLE1_SEED_SECONDS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim_core.rng import derive_rng
from sim_core.sonar.params import Beam
from sim_core.world import Forest, ForestSpec, Leaves, SpeciesSpec, build_forest, get_preset

__all__ = [
    "TABLE1_BEAMWIDTHS_DEG",
    "TABLE1_POSITIONS",
    "TABLE1_SEED_SECONDS",
    "Ping",
    "canopy_centers",
    "fig6_scene",
    "fig7_scene",
    "figure_eight_path",
    "leaf_cone",
    "maple_cluster",
    "table1_setups",
]

#: seed 000 Table 1 (s, MATLAB on a 2.1 GHz E5-2683v4): setup -> varying factor -> T = 1..5
TABLE1_SEED_SECONDS: dict[str, dict[int, tuple[float, ...]]] = {
    "circular": {
        1: (0.73, 0.77, 0.86, 0.93, 1.07),
        5: (0.88, 1.00, 1.19, 1.33, 1.52),
        10: (0.97, 1.21, 1.42, 1.72, 2.11),
        15: (1.03, 1.68, 1.92, 2.54, 3.03),
    },
    "fixed": {
        10: (0.73, 0.77, 0.86, 0.93, 1.07),
        20: (0.75, 0.82, 0.89, 0.96, 1.09),
        30: (0.79, 0.86, 0.97, 1.06, 1.23),
        40: (0.83, 0.91, 1.11, 1.19, 1.42),
        50: (0.96, 1.12, 1.33, 1.37, 1.63),
    },
}
TABLE1_POSITIONS = (1, 5, 10, 15)
TABLE1_BEAMWIDTHS_DEG = (10, 20, 30, 40, 50)
#: maple base positions of the Table 1 cluster (m); the first T are used for T trees
CLUSTER_XY = ((0.0, 0.0), (7.0, 1.5), (2.5, 7.0), (-5.5, 4.0), (-4.0, -5.5))


@dataclass(frozen=True, slots=True)
class Ping:
    """One ping of a scenario: a label and the :class:`Beam`."""

    label: str
    beam: Beam


def leaf_cone(
    m: int,
    rng: np.random.Generator,
    *,
    half_angle_rad: float = math.radians(8.0),
    r_lo: float = 1.0,
    r_hi: float = 8.0,
) -> Leaves:
    """``m`` synthetic leaves in a cone around +x from the origin (benchmark scenes).

    Ranges U[r_lo, r_hi] m, directions uniform over the cone's cross-section, isotropic normals,
    radii N(2.5 cm, 0.5 cm) truncated to [0, 0.5] m (seed 000 leaf size).
    """
    r = rng.uniform(r_lo, r_hi, m)
    th = half_angle_rad * np.sqrt(rng.uniform(0.0, 1.0, m))
    ph = rng.uniform(0.0, 2.0 * np.pi, m)
    st = np.sin(th)
    centers = np.stack([r * np.cos(th), r * st * np.cos(ph), r * st * np.sin(ph)], 1)
    normals = rng.normal(size=(m, 3))
    radii = np.clip(rng.normal(0.025, 0.005, m), 0.0, 0.5)
    return Leaves(centers, normals, radii, np.zeros(m, dtype=np.int32))


def canopy_centers(forest: Forest) -> NDArray[np.float64]:
    """Per tree, the centre of its leaves' bounding box, (T, 3) m (tree base if leafless)."""
    out = np.zeros((forest.n_trees, 3))
    out[:, :2] = forest.tree_xy
    ids = forest.leaves.tree_id
    for t in range(forest.n_trees):
        pts = forest.leaves.centers[ids == t]
        if pts.shape[0]:
            out[t] = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    return out


def _aim(position: NDArray[np.float64], target: NDArray[np.float64], bw_rad: float) -> Beam:
    axis = target - position
    if not float(np.linalg.norm(axis)) > 0.0:
        raise ValueError(f"cannot aim a beam from {position} at itself")
    return Beam(position, axis, bw_rad)


def fig6_scene(
    *, seed: int = 0, position: tuple[float, float, float] = (2.0, 6.0, 15.0)
) -> tuple[Leaves, list[Ping]]:
    """One maple at the origin and a sonar at ``position`` aimed at the leaves' box centre."""
    forest = build_forest(get_preset("single-maple"), seed=seed)
    pos = np.asarray(position, dtype=np.float64)
    box = 0.5 * (forest.leaves.centers.min(axis=0) + forest.leaves.centers.max(axis=0))
    pings = [Ping(f"BW {bw} deg", _aim(pos, box, math.radians(bw))) for bw in (10, 30, 50)]
    return forest.leaves, pings


def figure_eight_path(
    center: tuple[float, float],
    half_length: float,
    half_width: float,
    altitude: float,
    count: int,
    *,
    rotation_rad: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The "8" route (lemniscate of Gerono): ``count`` evenly spaced samples of one lap.

    x = L sin t, y = W sin t cos t (rotated by ``rotation_rad``, shifted to ``center``), at
    constant ``altitude``; t = 2 pi (k + 1/2) / count, so the crossing is never sampled twice.
    Returns positions (count, 3) m and headings (count,) rad (direction of travel, from +x
    towards +y). The lobes' centres sit near +-0.7 L along the rotated x axis; each lobe is W
    wide.
    """
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be a positive integer, got {count!r}")
    for name, value in (("half_length", half_length), ("half_width", half_width)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    t = 2.0 * np.pi * (np.arange(count) + 0.5) / count
    x = half_length * np.sin(t)
    y = half_width * np.sin(t) * np.cos(t)
    dx = half_length * np.cos(t)
    dy = half_width * np.cos(2.0 * t)
    c, s = math.cos(rotation_rad), math.sin(rotation_rad)
    pos = np.stack(
        [center[0] + c * x - s * y, center[1] + s * x + c * y, np.full(count, float(altitude))], 1
    )
    heading = np.arctan2(s * dx + c * dy, c * dx - s * dy)
    return pos, heading


def fig7_scene(*, seed: int = 0, count: int = 12) -> tuple[Forest, list[Ping], NDArray[np.float64]]:
    """Fig 5(d) forest, ``count`` pings on an "8" around the maple cluster and the hazelnut.

    Each ping aims at the nearest canopy centre; beamwidth ~ U[30, 65] deg from
    ``derive_rng(seed, "fig7", "beamwidth")``. Returns (forest, pings, headings).
    """
    forest = build_forest(get_preset("seed000-fig5d"), seed=seed)
    canopies = canopy_centers(forest)
    maple = forest.tree_species == "maple"
    a = canopies[maple, :2].mean(axis=0)
    b = canopies[~maple, :2].mean(axis=0) if (~maple).any() else a + np.array([10.0, 10.0])
    mid = 0.5 * (a + b)
    span = float(np.linalg.norm(b - a))
    pos, heading = figure_eight_path(
        (float(mid[0]), float(mid[1])),
        half_length=span / 2 / 0.7,
        half_width=14.0,
        altitude=8.0,
        count=count,
        rotation_rad=math.atan2(float(b[1] - a[1]), float(b[0] - a[0])),
    )
    rng = derive_rng(seed, "fig7", "beamwidth")
    widths = rng.uniform(30.0, 65.0, count)
    pings = []
    for k in range(count):
        nearest = canopies[int(np.argmin(np.linalg.norm(canopies[:, :2] - pos[k, :2], axis=1)))]
        pings.append(Ping(f"P{k + 1} BW {widths[k]:.0f} deg",
                          _aim(pos[k], nearest, math.radians(float(widths[k])))))
    return forest, pings, heading


def maple_cluster(trees: int, *, seed: int = 0) -> Forest:
    """The Table 1 cluster: the first ``trees`` (1..5) maples of :data:`CLUSTER_XY`."""
    if not 1 <= trees <= len(CLUSTER_XY):
        raise ValueError(f"trees must be in 1..{len(CLUSTER_XY)}, got {trees!r}")
    spec = ForestSpec(species=(SpeciesSpec("maple", tree="maple",
                                           positions=CLUSTER_XY[:trees]),))
    return build_forest(spec, seed=seed)


def table1_setups(forest: Forest) -> dict[str, dict[int, list[Ping]]]:
    """Pings of both Table 1 setups for one cluster.

    ``"circular"``: K -> K pings evenly on a circle of radius 2 m + the largest distance of a
    maple from the cluster centre, at z = 5 m, beamwidth 10 deg, each aimed at the canopy
    centre (mean of the canopy centres). ``"fixed"``: BW -> one ping from the circle's first
    point with that beamwidth (deg).
    """
    canopies = canopy_centers(forest)
    centre = canopies.mean(axis=0)
    radius = 2.0 + float(np.max(np.linalg.norm(forest.tree_xy - centre[:2], axis=1)))
    radius = max(radius, 6.0)

    def on_circle(k: int, count: int) -> NDArray[np.float64]:
        ang = 2.0 * np.pi * k / count
        return np.array([centre[0] + radius * math.cos(ang), centre[1] + radius * math.sin(ang),
                         5.0])

    circular = {
        n: [Ping(f"pos {k + 1}/{n}", _aim(on_circle(k, n), centre, math.radians(10.0)))
            for k in range(n)]
        for n in TABLE1_POSITIONS
    }
    fixed = {
        bw: [Ping(f"BW {bw}", _aim(on_circle(0, 1), centre, math.radians(bw)))]
        for bw in TABLE1_BEAMWIDTHS_DEG
    }
    return {"circular": circular, "fixed": fixed}
