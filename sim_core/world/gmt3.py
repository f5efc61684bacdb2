"""Seed 000 GMT3 ternary L-system skeleton and its own leaves (spec §2A.1-2A.2).

Every segment at a branch point spawns three children: left (h = −angle, ratio ``ratio_side``),
centre (h = 0, ratio ``ratio_centre``) and right (h = +angle, ``ratio_side``). A child of a
vertical parent is ``rotz(α)·(0, ℓ sin h, ℓ cos h)`` with the whorl azimuth α advancing by the
divergence angle per level; any other child is the parent direction rotated by h towards the
horizontal perpendicular of the parent. Radius shrinks by ``radius_ratio`` per level.

Variants: ``"forest"`` (``g → d(g)[g)+g)``, ``levels`` iterations; branch points on the trunk
sprout at a random extra height ``U(sprout)``) and ``"single"`` (``d(d)+d)[d(d)+d)`` doubled by a
copy rotated 90° about z and lifted by ``ratio_centre·trunk/2``).

Leaves (ginkgo scripts): each internal segment carries ``nodes`` nodes at fractions i/(nodes+1)
with ``leaves_per_node`` leaves whose normals are perpendicular to the branch, rotated about it by
360°/nodes·(i−1) + 10°·(leaf−1), centres pushed out along the normal by ``U(0,1)·node_jitter``;
each terminal segment has the same along-branch leaves at ``nodes − 1`` nodes plus
``tip_leaves`` leaves at the tip (jitter ``U(0,1)·tip_jitter`` per axis, normal = unit branch
direction + U(0, 0.1) per component, normalised).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sim_core.world.geometry import perpendicular, rotate, unit

__all__ = ["Skeleton", "grow_skeleton", "skeleton_leaves"]

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Branch segments in model units, z up, tree base at the origin.

    Attributes:
        start, vec: (S, 3) segment start points and vectors.
        radius: (S,) branch radius.
        level: (S,) growth level (0 = trunk).
        terminal: (S,) True for apex segments ``g``.
        main_axis: (S,) True on the vertical leader.
    """

    start: F64
    vec: F64
    radius: F64
    level: NDArray[np.int64]
    terminal: NDArray[np.bool_]
    main_axis: NDArray[np.bool_]

    @property
    def end(self) -> F64:
        return self.start + self.vec


def _children(
    vec: F64, h: float, ratio: float, azimuth: F64, vertical: NDArray[np.bool_]
) -> F64:
    """Child vectors for one child slot (h radians) of every parent ``vec (N, 3)``."""
    length = np.linalg.norm(vec, axis=1)
    out = np.empty_like(vec)
    v = vertical
    if v.any():
        ell = ratio * length[v]
        local = np.stack([np.zeros_like(ell), ell * np.sin(h), ell * np.cos(h)], axis=1)
        c, s = np.cos(azimuth[v]), np.sin(azimuth[v])
        out[v, 0] = c * local[:, 0] - s * local[:, 1]
        out[v, 1] = s * local[:, 0] + c * local[:, 1]
        out[v, 2] = local[:, 2]
    nv = ~v
    if nv.any():
        p = vec[nv]
        horiz = np.stack([-p[:, 1], p[:, 0], np.zeros(p.shape[0])], axis=1)
        phat = unit(horiz)
        out[nv] = ratio * (np.cos(h) * p + np.sin(h) * length[nv, None] * phat)
    return out


def grow_skeleton(
    rng: np.random.Generator,
    *,
    variant: Literal["forest", "single"] = "forest",
    levels: int = 6,
    trunk: float = 2.0,
    angle_deg: float = 50.0,
    ratio_side: float = 0.62,
    ratio_centre: float = 0.826,
    divergence_deg: float = -43.75,
    radius0: float = 0.04,
    radius_ratio: float = 0.7,
    sprout: tuple[float, float] = (0.2, 0.7),
    twist_max_deg: float = 15.0,
) -> Skeleton:
    """Grow a GMT3 skeleton (model units). ``levels == 0`` is the bare trunk.

    Random draws: the whole tree's azimuth ``U(0, 2π)``, a per-whorl twist ``U(0, twist_max)``
    added to the whorl azimuth (the seed's ``rand_a``), and the sprout heights of the trunk whorls.
    """
    if levels < 0:
        raise ValueError(f"levels must be >= 0, got {levels}")
    if variant == "single":
        return _single(rng, trunk=trunk, angle_deg=angle_deg, ratio_side=ratio_side,
                       ratio_centre=ratio_centre, radius0=radius0, radius_ratio=radius_ratio)
    h = np.radians(angle_deg)
    beta = np.radians(divergence_deg)
    base_az = rng.uniform(0.0, 2.0 * np.pi)
    starts = [np.zeros((1, 3))]
    vecs = [np.array([[0.0, 0.0, trunk]])]
    radii = [np.array([radius0])]
    lvls = [np.zeros(1, dtype=np.int64)]
    mains = [np.ones(1, dtype=bool)]
    for k in range(levels):
        pv, ps, pr, pm = vecs[-1], starts[-1], radii[-1], mains[-1]
        n = pv.shape[0]
        if pm.any():
            # sprout: the trunk branch point rises by U(sprout); lengthen the leader to match
            lift = rng.uniform(sprout[0], sprout[1], size=int(pm.sum()))
            pv = pv.copy()
            pv[pm, 2] += lift
            vecs[-1] = pv
        horiz = np.hypot(pv[:, 0], pv[:, 1])
        vertical = horiz <= 1e-12 * np.abs(pv[:, 2])
        twist = np.radians(rng.uniform(0.0, twist_max_deg, size=n))
        az = base_az + beta * (k + 1) + twist
        child_start = ps + pv
        kids = [
            (_children(pv, -h, ratio_side, az, vertical), False),
            (_children(pv, 0.0, ratio_centre, az, vertical), True),
            (_children(pv, h, ratio_side, az, vertical), False),
        ]
        starts.append(np.concatenate([child_start] * 3))
        vecs.append(np.concatenate([kv for kv, _ in kids]))
        radii.append(np.concatenate([pr * radius_ratio] * 3))
        lvls.append(np.full(3 * n, k + 1, dtype=np.int64))
        mains.append(np.concatenate([pm & centre for _, centre in kids]))
    level = np.concatenate(lvls)
    return Skeleton(
        start=np.concatenate(starts),
        vec=np.concatenate(vecs),
        radius=np.concatenate(radii),
        level=level,
        terminal=level == levels,
        main_axis=np.concatenate(mains),
    )


def _single(
    rng: np.random.Generator,
    *,
    trunk: float,
    angle_deg: float,
    ratio_side: float,
    ratio_centre: float,
    radius0: float,
    radius_ratio: float,
) -> Skeleton:
    """``d(d)+d)[d(d)+d)`` plus its copy rotated 90° and lifted (GMT3.m single tree)."""
    h = np.radians(angle_deg)
    az0 = rng.uniform(0.0, 2.0 * np.pi)
    t = np.array([[0.0, 0.0, trunk]])
    vert = np.array([True])
    az = np.array([az0])
    left = _children(t, -h, ratio_side, az, vert)
    centre = _children(t, 0.0, ratio_centre, az, vert)
    right = _children(t, h, ratio_side, az, vert)
    cl = _children(centre, -h, ratio_side, az, vert)
    cr = _children(centre, h, ratio_side, az, vert)
    vec = np.concatenate([t, left, right, centre, cl, cr])
    start = np.concatenate([np.zeros((1, 3)), t, t, t, t + centre, t + centre])
    level = np.array([0, 1, 1, 1, 2, 2])
    lift = np.array([0.0, 0.0, ratio_centre * trunk / 2.0])
    c, s = 0.0, 1.0  # rotz(90°)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    start2 = start[1:] @ rot.T + lift
    vec2 = vec[1:] @ rot.T
    radius = radius0 * radius_ratio ** level.astype(np.float64)
    return Skeleton(
        start=np.concatenate([start, start2]),
        vec=np.concatenate([vec, vec2]),
        radius=np.concatenate([radius, radius[1:]]),
        level=np.concatenate([level, level[1:]]),
        terminal=np.zeros(11, dtype=bool),
        main_axis=np.concatenate([[True, False, False, True, False, False], np.zeros(5, bool)]),
    )


def skeleton_leaves(
    skel: Skeleton,
    rng: np.random.Generator,
    *,
    nodes: int = 4,
    leaves_per_node: int = 4,
    tip_leaves: int = 4,
    node_jitter: float = 0.1,
    tip_jitter: float = 0.05,
    min_level: int = 1,
) -> tuple[F64, F64]:
    """Leaf centres and unit normals (model units) along branches and at tips.

    Segments below ``min_level`` (the trunk by default) carry no leaves.
    """
    use = skel.level >= min_level
    groups_c: list[F64] = []
    groups_n: list[F64] = []
    for terminal, m in ((False, nodes), (True, nodes - 1)):
        sel = use & (skel.terminal == terminal)
        if m <= 0 or not sel.any():
            continue
        start, vec = skel.start[sel], skel.vec[sel]
        s = start.shape[0]
        frac = np.arange(1, m + 1) / (m + 1)
        node = start[:, None, None, :] + frac[None, :, None, None] * vec[:, None, None, :]
        node = np.broadcast_to(node, (s, m, leaves_per_node, 3)).reshape(-1, 3)
        axis = np.repeat(unit(vec), m * leaves_per_node, axis=0)
        perp = np.repeat(perpendicular(vec), m * leaves_per_node, axis=0)
        ang = (
            np.radians(360.0 / m) * np.arange(m)[:, None]
            + np.radians(10.0) * np.arange(leaves_per_node)[None, :]
        )
        ang = np.broadcast_to(ang, (s, m, leaves_per_node)).reshape(-1)
        normal = rotate(perp, axis, ang)
        centre = node + node_jitter * rng.random(node.shape[0])[:, None] * normal
        groups_c.append(centre)
        groups_n.append(normal)
    tips = use & skel.terminal
    if tip_leaves > 0 and tips.any():
        end = skel.end[tips]
        vec = skel.vec[tips]
        k = end.shape[0] * tip_leaves
        centre = np.repeat(end, tip_leaves, axis=0) + tip_jitter * rng.random((k, 3))
        normal = unit(np.repeat(unit(vec), tip_leaves, axis=0) + 0.1 * rng.random((k, 3)))
        groups_c.append(centre)
        groups_n.append(normal)
    if not groups_c:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(groups_c), np.concatenate(groups_n)
