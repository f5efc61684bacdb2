"""Figures: each plot function writes a PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil_bridge.plots.world import plot_forest_3d, plot_top_view, plot_tree_side
from sim_core.world import build_forest, get_preset
from sim_core.world.trees import get_tree_model

PNG = b"\x89PNG\r\n\x1a\n"


def test_plots_write_png(tmp_path: Path) -> None:
    forest = build_forest(get_preset("seed000-fig5d"), seed=1)
    plot_top_view(forest, tmp_path / "top.png")
    plot_forest_3d(forest, tmp_path / "3d.png")
    geo = get_tree_model("maple").grow(np.random.default_rng(0), branches=True)
    plot_tree_side(geo, tmp_path / "side.png")
    for name in ("top.png", "3d.png", "side.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == PNG and len(data) > 5000
