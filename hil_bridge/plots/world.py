"""Figures of trees and forests (matplotlib, Agg backend, PNG files).

* :func:`plot_top_view` — tree positions by species (seed 001 Fig 8);
* :func:`plot_tree_side` — one tree in side view, branches and leaves (seed 000 Fig 5a-c);
* :func:`plot_forest_3d` — 3-D leaf scatter of a forest (seed 000 Fig 5d, seed 001 Figs 9-10);
* :func:`plot_forest` — top view and 3-D scatter side by side (the CLI's ``--plot``).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes

from sim_core.world.forest import Forest
from sim_core.world.trees import TreeGeometry

__all__ = [
    "plot_forest",
    "plot_forest_3d",
    "plot_top_view",
    "plot_tree_side",
    "plot_trees_side",
    "write_gallery",
]

_MAX_POINTS = 60_000


def _colors(names: tuple[str, ...]) -> dict[str, tuple[float, float, float, float]]:
    cmap = plt.get_cmap("tab10")
    return {n: cmap(i % 10) for i, n in enumerate(names)}


def _top(ax: Axes, forest: Forest) -> None:
    colors = _colors(forest.species)
    for name in forest.species:
        sel = forest.tree_species == name
        ax.scatter(forest.tree_xy[sel, 0], forest.tree_xy[sel, 1], s=30, color=colors[name],
                   label=f"{name} ({int(sel.sum())})", edgecolors="k", linewidths=0.4)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("tree positions by species")
    if forest.species:
        ax.legend(fontsize=7, loc="best")


def _scatter3d(ax: Axes, forest: Forest, rng: np.random.Generator) -> None:
    leaves = forest.leaves
    idx = np.arange(len(leaves))
    if idx.size > _MAX_POINTS:
        idx = np.sort(rng.choice(idx.size, _MAX_POINTS, replace=False))
    colors = _colors(forest.species)
    species_of_leaf = forest.tree_species[leaves.tree_id[idx]] if idx.size else np.zeros(0, str)
    for name in forest.species:
        sel = idx[species_of_leaf == name]
        c = leaves.centers[sel]
        ax.scatter(c[:, 0], c[:, 1], c[:, 2], s=0.3, color=colors[name], label=name)  # type: ignore[misc]
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")  # type: ignore[attr-defined]
    ax.set_title(f"{forest.n_trees} trees, {len(leaves)} leaves")
    if idx.size:
        span = np.ptp(leaves.centers[idx], axis=0)
        # metric axes, with height exaggerated up to a quarter of the ground extent
        horiz = max(float(span[:2].max()), 1e-6)
        aspect = (max(span[0], 1e-6), max(span[1], 1e-6), max(float(span[2]), 0.25 * horiz))
        ax.set_box_aspect(aspect)  # type: ignore[arg-type]
        ax.legend(fontsize=7, markerscale=12, loc="upper left")


def plot_top_view(forest: Forest, path: str | Path) -> None:
    """Tree positions coloured by species (seed 001 Fig 8)."""
    fig, ax = plt.subplots(figsize=(6, 6))
    _top(ax, forest)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_forest_3d(forest: Forest, path: str | Path, *, seed: int = 0) -> None:
    """3-D scatter of leaf centres by species (subsampled to 60 000 points)."""
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    _scatter3d(ax, forest, np.random.default_rng(seed))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_forest(forest: Forest, path: str | Path, *, title: str | None = None) -> None:
    """Top view and 3-D leaf scatter in one PNG."""
    fig = plt.figure(figsize=(13, 6))
    ax1 = fig.add_subplot(1, 2, 1)
    _top(ax1, forest)
    ax2 = fig.add_subplot(1, 2, 2, projection="3d")
    _scatter3d(ax2, forest, np.random.default_rng(0))
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _side(ax: Axes, geo: TreeGeometry, title: str) -> None:
    if geo.seg_start.shape[0]:
        from matplotlib.collections import LineCollection

        segs = np.stack([geo.seg_start[:, [0, 2]], geo.seg_end[:, [0, 2]]], axis=1)
        widths = np.clip(geo.seg_radius * 40.0, 0.2, 4.0)  # points; ~4 pt for a 10 cm radius
        ax.add_collection(LineCollection(list(segs), colors="saddlebrown", linewidths=widths))
    ax.scatter(geo.centers[:, 0], geo.centers[:, 2], s=1.0, color="forestgreen", zorder=3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale()
    ax.set_title(title or f"{geo.radii.shape[0]} leaves, {geo.height:.1f} m tall", fontsize=9)


def plot_tree_side(geo: TreeGeometry, path: str | Path, *, title: str = "") -> None:
    """One tree in side view (x-z): branches as lines, leaf centres as green dots (Fig 5c)."""
    fig, ax = plt.subplots(figsize=(6, 7))
    _side(ax, geo, title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_trees_side(geos: list[tuple[str, TreeGeometry]], path: str | Path) -> None:
    """Several trees side by side in side view (seed 001 Fig 7)."""
    fig, axes = plt.subplots(1, max(len(geos), 1), figsize=(4 * max(len(geos), 1), 6))
    for ax, (name, geo) in zip(np.atleast_1d(axes), geos, strict=False):
        _side(ax, geo, f"{name}: {geo.radii.shape[0]} leaves, {geo.height:.1f} m")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_gallery(out_dir: str | Path, *, seed: int = 1) -> list[Path]:
    """The documentation figures (docs/figures/world): Figs 5, 5d, 7, 8, 9 analogues."""
    from hil_bridge.files.world import load_forest_files, load_tree_model
    from sim_core.rng import derive_rng
    from sim_core.world.forest import build_forest
    from sim_core.world.presets import get_preset

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    spec9 = get_preset("seed001-fig9")
    fig9 = build_forest(spec9, seed=seed, files=load_forest_files(spec9))
    paths.append(out / "seed001_fig8_top_view.png")
    plot_top_view(fig9, paths[-1])
    paths.append(out / "seed001_fig9_forest_3d.png")
    plot_forest_3d(fig9, paths[-1], seed=seed)
    fig5d = build_forest(get_preset("seed000-fig5d"), seed=seed)
    paths.append(out / "seed000_fig5d_forest_3d.png")
    plot_forest_3d(fig5d, paths[-1], seed=seed)
    gmt3 = [
        (name, load_tree_model(name).grow(derive_rng(seed, "gallery", name), branches=True))
        for name in ("maple-single", "maple", "hazelnut-bush")
    ]
    paths.append(out / "seed000_fig5_gmt3_side.png")
    plot_trees_side(gmt3, paths[-1])
    species = [
        (name, load_tree_model(name).grow(derive_rng(seed, "gallery", name), branches=True))
        for name in ("tree4", "tree5", "tree6", "tree7")
    ]
    paths.append(out / "seed001_fig7_species_side.png")
    plot_trees_side(species, paths[-1])
    return paths
