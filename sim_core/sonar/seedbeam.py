"""The seed's 2020 beam (``EchoParams(seed2020=True)``): a Gaussian in raw azimuth/elevation
differences, evaluated exactly at each leaf or read from the paper code's 1° grid.

The paper's ``filter_leaves_beamG.m`` (docs/spec/seed_models.md §1.3) evaluates the beam on a
grid of 361 azimuth × 181 elevation nodes centred on the beam, az0 + [-pi, pi] and
el0 + [-pi/2, pi/2], and gives each leaf the value of the nearest node in azimuth and, apart,
in elevation (the first of two equally near nodes). Before the lookup a leaf's azimuth is moved
by ±2 pi into the grid's span by the seed's own rule (:func:`seed_wrap`). Elevations past the
grid's ends (beams away from the horizon) take the end node. The grid mode reproduces all of
it, including the node positions of GNU Octave 7.3's ``linspace`` (which builds the sequence
from both ends; the seed's outputs in ``tests/data/seed000_matlab`` were made with it).

Angles come from MATLAB's ``cart2sph``: azimuth atan2(y, x) from +x towards +y, elevation
atan2(z, hypot(x, y)) from the xy-plane, for the offset leaf - sonar and for the boresight.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "AZ_NODES",
    "EL_NODES",
    "BeamLookup",
    "grid_nodes",
    "nearest_node",
    "octave_linspace",
    "off_axis",
    "seed_wrap",
    "sph_angles",
]

F64 = NDArray[np.float64]
BeamLookup = Literal["exact", "grid"]

#: nodes of the seed's beam grid: 1° steps over 360° of azimuth and 180° of elevation
AZ_NODES = 361
EL_NODES = 181


def octave_linspace(x1: float, x2: float, n: int) -> F64:
    """``linspace(x1, x2, n)`` of GNU Octave 7.3, bit for bit, shape (n,).

    Octave builds the sequence from both ends with delta = (x2 - x1)/(n - 1): element i is
    x1 + i delta in the first half and x2 - (n-1-i) delta in the second, the middle one of an
    odd n is (x1 + x2)/2 (0 if x1 == -x2); the ends are x1 and x2 exactly.
    """
    if n < 2:
        raise ValueError(f"octave_linspace needs n >= 2, got {n}")
    delta = (x2 - x1) / (n - 1)
    half = n // 2
    i = np.arange(1, half, dtype=np.float64)
    out = np.empty(n)
    out[0], out[-1] = x1, x2
    out[1:half] = x1 + i * delta
    out[n - 2 : n - half - 1 : -1] = x2 - i * delta
    if n % 2:
        out[half] = 0.0 if x1 == -x2 else (x1 + x2) / 2.0
    return out


def sph_angles(x: F64, y: F64, z: F64) -> tuple[F64, F64]:
    """MATLAB ``cart2sph`` angles of offsets (x, y, z) m, each (M,): azimuth, elevation (rad)."""
    return np.arctan2(y, x), np.arctan2(z, np.hypot(x, y))


def grid_nodes(az0: float, el0: float) -> tuple[F64, F64]:
    """The seed's grid centred on the beam (az0, el0) rad: azimuth (361,), elevation (181,)."""
    return (
        octave_linspace(az0 - math.pi, az0 + math.pi, AZ_NODES),
        octave_linspace(el0 - math.pi / 2, el0 + math.pi / 2, EL_NODES),
    )


def seed_wrap(az: F64, az0: float) -> F64:
    """Leaf azimuths (M,) rad moved by ±2 pi as the seed does before its lookup.

    For az0 in [0, pi], leaves in [-pi, -pi + az0) gain 2 pi; for az0 in (-pi, 0), leaves in
    [az0 + pi, pi] lose 2 pi. Any other az0 (only -pi exactly, a boresight along -x with y = -0)
    moves nothing: the seed's own quirk, kept.
    """
    if 0.0 <= az0 <= math.pi:
        return np.where((az >= -math.pi) & (az < -math.pi + az0), az + 2.0 * math.pi, az)
    if -math.pi < az0 < 0.0:
        return np.where((az >= az0 + math.pi) & (az <= math.pi), az - 2.0 * math.pi, az)
    return az


def nearest_node(values: F64, nodes: F64) -> NDArray[np.intp]:
    """Index of the node nearest each value, the first of equally near ones, (M,).

    ``nodes`` (K,) are increasing and evenly spaced (up to rounding); values past either end
    take the end node (MATLAB's ``[~, i] = min(abs(v - nodes), [], 2)``).
    """
    last = nodes.shape[0] - 1
    step = (nodes[-1] - nodes[0]) / last
    guess = np.rint((values - nodes[0]) / step)
    np.clip(guess, 0, last, out=guess)
    centre = guess.astype(np.intp)
    # the nearest node is within one of the guess; candidates in increasing order, so argmin's
    # first minimum is the first nearest node
    cand = np.clip(centre[:, None] + np.array([-1, 0, 1]), 0, last)
    dist = np.abs(values[:, None] - nodes[cand])
    return np.take_along_axis(cand, np.argmin(dist, axis=1)[:, None], axis=1)[:, 0]


def off_axis(dx: F64, dy: F64, dz: F64, axis: F64, lookup: str) -> tuple[F64, F64]:
    """(Δaz, Δel) rad, each (M,), of leaves at offsets (dx, dy, dz) m from a beam along ``axis``.

    ``exact``: the leaf's own differences, Δaz wrapped into [-pi, pi). ``grid``: those of the
    nearest node of the seed's grid (:func:`grid_nodes`, :func:`seed_wrap`,
    :func:`nearest_node`), node - centre as the seed computes it.
    """
    az, el = sph_angles(dx, dy, dz)
    az0 = math.atan2(float(axis[1]), float(axis[0]))
    el0 = math.atan2(float(axis[2]), math.hypot(float(axis[0]), float(axis[1])))
    if lookup == "exact":
        daz = np.mod(az - az0 + np.pi, 2.0 * np.pi) - np.pi
        return daz, el - el0
    if lookup != "grid":
        raise ValueError(f"unknown beam lookup {lookup!r}; expected 'exact' or 'grid'")
    az_nodes, el_nodes = grid_nodes(az0, el0)
    daz = az_nodes[nearest_node(seed_wrap(az, az0), az_nodes)] - az0
    return daz, el_nodes[nearest_node(el, el_nodes)] - el0
