"""Inhomogeneous Poisson processes by thinning, intensities, and minimum-distance thinning.

Thinning (Adams, Murray & MacKay, Algorithm 1; spec §2A.5): on a box B draw
``n ~ Poisson(λ*·|B|)`` uniform points and keep each with probability ``min(λ(s), λ*) / λ*``
(λ clamped to its bound λ*). The kept points are an IPP with intensity ``min(λ, λ*)``.

An intensity is any callable ``λ(x, y) -> ndarray`` (trees per m², vectorised over arrays of
equal shape) together with an upper bound ``λ*``. Provided forms: :class:`SEMixture` (seed 000's
mixture of squared-exponential bumps ``C·exp(−(x−a)²/h − (y−b)²/l)``, raw divisors h, l in m²),
:class:`Homogeneous`, and :class:`KDEIntensity` (a Gaussian kernel density estimate of a real tree
map, scaled to its number of trees, so a real site can be mimicked).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = [
    "Homogeneous",
    "Intensity",
    "KDEIntensity",
    "SEMixture",
    "TreeMap",
    "expected_count",
    "grid_upper_bound",
    "min_distance_thin",
    "sample_ipp",
    "tree_map_positions",
]

F64 = NDArray[np.float64]
Box = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax (metres)
IntensityFn = Callable[[F64, F64], ArrayLike]


class Intensity(ABC):
    """Base of the provided intensities: ``__call__(x, y)`` plus ``upper_bound(box)``."""

    @abstractmethod
    def __call__(self, x: F64, y: F64) -> F64:
        """λ at the points (x, y) (trees/m²), same shape as x."""

    @abstractmethod
    def upper_bound(self, box: Box | None) -> float:
        """A λ* with λ ≤ λ* on ``box`` (``None``: the whole plane)."""


@dataclass(frozen=True)
class SEMixture(Intensity):
    """``λ(x, y) = Σ_k peak_k · exp(−(x − a_k)²/h_k − (y − b_k)²/l_k)`` (trees/m²).

    ``kernels`` rows are ``(peak, a, b, h, l)``; h and l are the raw divisors (m²) of the seed
    code (the paper's h², l²). ∫λ over the plane = Σ peak·π·√(h·l).
    """

    kernels: tuple[tuple[float, float, float, float, float], ...]

    def __post_init__(self) -> None:
        for i, (peak, _a, _b, hx, hy) in enumerate(self.kernels):
            if not (np.isfinite(peak) and peak >= 0):
                raise ValueError(f"kernels[{i}].peak must be a finite intensity >= 0, got {peak}")
            if not (hx > 0 and hy > 0):
                raise ValueError(f"kernels[{i}] divisors h, l must be > 0, got {hx}, {hy}")

    def __call__(self, x: F64, y: F64) -> F64:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        out = np.zeros(np.broadcast(x, y).shape)
        for peak, a, b, hx, hy in self.kernels:
            out += peak * np.exp(-((x - a) ** 2) / hx - (y - b) ** 2 / hy)
        return out

    def upper_bound(self, box: Box | None) -> float:
        if not self.kernels:
            return 0.0
        if box is None:
            return float(sum(k[0] for k in self.kernels))
        # each bump is largest at the box point closest to its centre
        x0, y0, x1, y1 = box
        total = 0.0
        for peak, a, b, hx, hy in self.kernels:
            cx, cy = np.clip(a, x0, x1), np.clip(b, y0, y1)
            total += peak * float(np.exp(-((cx - a) ** 2) / hx - (cy - b) ** 2 / hy))
        return total

    def integral(self) -> float:
        """∫λ over the whole plane."""
        return float(sum(p * np.pi * np.sqrt(hx * hy) for p, _a, _b, hx, hy in self.kernels))


@dataclass(frozen=True)
class Homogeneous(Intensity):
    """Constant intensity ``rate`` trees/m²."""

    rate: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rate) and self.rate >= 0):
            raise ValueError(f"rate must be a finite intensity >= 0, got {self.rate}")

    def __call__(self, x: F64, y: F64) -> F64:
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, self.rate)

    def upper_bound(self, box: Box | None) -> float:
        return self.rate


class KDEIntensity(Intensity):
    """Intensity estimated from a tree map: ``λ(s) = scale · N · kde(s)`` (Gaussian KDE).

    ``points (N, 2)`` metres; ``bandwidth`` is scipy's ``bw_method`` (``None``: Scott's rule, a
    float: the factor). ∫λ over the plane = scale·N, so ``scale = 1`` mimics the site's density.
    """

    def __init__(self, points: ArrayLike, *, bandwidth: float | None = None, scale: float = 1.0):
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3:
            raise ValueError(f"KDE needs a tree map of at least 3 (x, y) points, got {pts.shape}")
        if not (np.isfinite(scale) and scale >= 0):
            raise ValueError(f"scale must be a finite number >= 0, got {scale}")
        self.points = pts
        self.scale = float(scale)
        from scipy.stats import gaussian_kde  # here: scipy.stats costs every server 0.4 s

        cov = np.atleast_2d(gaussian_kde(pts.T, bw_method=bandwidth).covariance)
        self._inv = np.linalg.inv(cov)
        self._peak = 1.0 / (2.0 * np.pi * np.sqrt(np.linalg.det(cov)))
        self._sd = np.sqrt(np.diag(cov))
        self._bound: float | None = None

    def __call__(self, x: F64, y: F64) -> F64:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast(x, y).shape
        q = np.column_stack([np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()])
        out = np.zeros(q.shape[0])
        chunk = max(1, 4_000_000 // self.points.shape[0])
        for a in range(0, q.shape[0], chunk):
            dx = q[a : a + chunk, 0, None] - self.points[None, :, 0]  # (m, N)
            dy = q[a : a + chunk, 1, None] - self.points[None, :, 1]
            ia = self._inv
            m2 = ia[0, 0] * dx * dx + (ia[0, 1] + ia[1, 0]) * dx * dy + ia[1, 1] * dy * dy
            out[a : a + chunk] = np.exp(-0.5 * m2).sum(axis=1)
        return (self.scale * self._peak * out).reshape(shape)

    def upper_bound(self, box: Box | None) -> float:
        # exact bound: every kernel at its peak; tightened by a fine grid over the support
        if self._bound is None:
            loose = self.scale * self.points.shape[0] * self._peak
            lo = self.points.min(axis=0) - 4 * self._sd
            hi = self.points.max(axis=0) + 4 * self._sd
            box_all = (lo[0], lo[1], hi[0], hi[1])
            grid = grid_upper_bound(self, box_all, spacing=self._sd.min() / 4)
            self._bound = float(min(loose, grid))
        return self._bound


def grid_upper_bound(fn: IntensityFn, box: Box, *, spacing: float, margin: float = 1.05) -> float:
    """``margin ×`` the maximum of ``fn`` on a grid of ``spacing`` over ``box`` (≤ 512² points).

    A bound for smooth intensities whose features are wider than a few grid spacings; thinning
    clamps λ to it, so an underestimate only flattens the highest peaks.
    """
    x0, y0, x1, y1 = box
    nx = int(np.clip(np.ceil((x1 - x0) / spacing) + 1, 2, 512))
    ny = int(np.clip(np.ceil((y1 - y0) / spacing) + 1, 2, 512))
    gx, gy = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny))
    values = np.asarray(fn(gx, gy), dtype=np.float64)
    _check_values(values, gx, gy)
    return margin * float(values.max()) if values.size else 0.0


def _check_values(values: F64, x: F64, y: F64) -> None:
    bad = ~np.isfinite(values) | (values < 0)
    if bad.any():
        i = int(np.flatnonzero(bad.ravel())[0])
        raise ValueError(
            f"intensity must be finite and >= 0, got {float(values.ravel()[i])!r} at "
            f"({np.ravel(x)[i]:.6g}, {np.ravel(y)[i]:.6g})"
        )


def expected_count(lam_max: float, box: Box) -> float:
    """Expected number of candidate points ``λ*·|box|``."""
    x0, y0, x1, y1 = box
    return lam_max * max(x1 - x0, 0.0) * max(y1 - y0, 0.0)


def sample_ipp(
    intensity: IntensityFn,
    box: Box,
    rng: np.random.Generator,
    *,
    lam_max: float | None = None,
    max_expected: float = 1e6,
) -> F64:
    """Points ``(n, 2)`` of an IPP with intensity ``intensity`` on ``box`` (thinning).

    ``lam_max`` is the bound λ*; ``None`` takes ``intensity.upper_bound(box)`` for an
    :class:`Intensity`, else a grid estimate (:func:`grid_upper_bound`). ``λ*·|box|`` above
    ``max_expected`` raises ``ValueError`` ("huge intensity") before anything is drawn; a negative
    or non-finite λ raises ``ValueError`` naming the value and the point.
    """
    x0, y0, x1, y1 = box
    if not (x1 >= x0 and y1 >= y0) or not np.all(np.isfinite(box)):
        raise ValueError(f"box must be finite (xmin, ymin, xmax, ymax), got {box}")
    if lam_max is None:
        if isinstance(intensity, Intensity):
            lam_max = intensity.upper_bound(box)
        else:
            spacing = max(x1 - x0, y1 - y0) / 256 or 1.0
            lam_max = grid_upper_bound(intensity, box, spacing=spacing)
    if not (np.isfinite(lam_max) and lam_max >= 0):
        raise ValueError(f"intensity bound lam_max must be a finite number >= 0, got {lam_max}")
    mean = expected_count(lam_max, box)
    if mean > max_expected:
        raise ValueError(
            f"huge intensity: λ*·area = {lam_max:.6g}/m² × {mean / max(lam_max, 1e-300):.6g} m² "
            f"= {mean:.6g} expected candidate trees > cap {max_expected:.6g}"
        )
    n = int(rng.poisson(mean))
    pts = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)])
    if n == 0 or lam_max == 0:
        return np.zeros((0, 2))
    lam = np.asarray(intensity(pts[:, 0], pts[:, 1]), dtype=np.float64)
    if lam.shape != (n,):
        raise ValueError(f"intensity returned shape {lam.shape} for {n} points; expected ({n},)")
    _check_values(lam, pts[:, 0], pts[:, 1])
    keep = rng.random(n) * lam_max < np.minimum(lam, lam_max)
    return pts[keep]


def min_distance_thin(points: ArrayLike, d_min: float) -> NDArray[np.bool_]:
    """Greedy thinning in the given order: keep a point unless it lies closer than ``d_min`` to
    an already kept point (seed 001 ``Untitled.ipynb``). Returns the keep mask."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    keep = np.ones(pts.shape[0], dtype=bool)
    if d_min <= 0 or pts.shape[0] < 2:
        return keep
    tree = cKDTree(pts)
    pairs = tree.query_pairs(d_min, output_type="ndarray")
    if pairs.size == 0:
        return keep
    # only pairs closer than d_min (query_pairs includes distance == d_min)
    dist = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    pairs = pairs[dist < d_min]
    earlier: list[list[int]] = [[] for _ in range(pts.shape[0])]
    for i, j in pairs:
        a, b = (int(i), int(j)) if i < j else (int(j), int(i))
        earlier[b].append(a)
    for i in range(pts.shape[0]):
        if any(keep[j] for j in earlier[i]):
            keep[i] = False
    return keep


@dataclass(frozen=True, eq=False)
class TreeMap:
    """The rows of a tree map (a CSV ``x, y[, species]``, read by ``hil_bridge.files.world``):
    ``xy`` (T, 2) finite positions in file units, ``labels`` the species column as written (a
    name, a 1-based index, or None) and ``lines`` the file line of each row, so that messages
    name ``source:line``."""

    xy: F64
    labels: tuple[str | None, ...]
    lines: tuple[int, ...]
    source: str = "<tree map>"


def tree_map_positions(
    tree_map: TreeMap, *, scale: float = 1.0, species_names: Sequence[str] = ()
) -> tuple[F64, list[str | None]]:
    """Positions and species of a tree map's rows.

    Coordinates are multiplied by ``scale`` (metres per file unit). A label may be a name or a
    1-based index into ``species_names`` (checked when names are given; errors name
    ``source:line``); returns ``(xy (T, 2) m, species per row or None)``.
    """
    species: list[str | None] = []
    for lineno, label in zip(tree_map.lines, tree_map.labels, strict=True):
        where = f"{tree_map.source}:{lineno}"
        if label is not None and species_names:
            if label.isdigit():
                k = int(label)
                if not 1 <= k <= len(species_names):
                    raise ValueError(
                        f"{where}: species index {k} out of range 1..{len(species_names)}"
                    )
                label = species_names[k - 1]
            elif label not in species_names:
                raise ValueError(
                    f"{where}: unknown species {label!r}; expected one of "
                    f"{list(species_names)} or a 1-based index"
                )
        species.append(label)
    xy = np.asarray(tree_map.xy, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([xy[:, 0] * scale, xy[:, 1] * scale]).reshape(-1, 2), species
