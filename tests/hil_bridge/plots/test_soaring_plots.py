"""Figures: paths, agent series and survival histograms are written as PNGs."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil_bridge.plots.soaring import plot_agent_series, plot_survival_histograms, plot_trends
from sim_core.soaring import Law, run


def test_agent_series_and_histograms(tmp_path: Path) -> None:
    tr = run(Law().replace(totalTime=30.0, numAgents=4), trace=True).trace
    assert tr is not None
    p = plot_agent_series(tr, [0, 3], tmp_path / "a.png", t_range=(0.0, 20.0))
    assert p.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="out of range"):
        plot_agent_series(tr, [4], tmp_path / "b.png")
    rows = [{"numThermals": n, "survivingPercent": s}
            for n, s in ((3, 10.0), (3, 40.0), (12, 90.0), (12, 100.0))]
    h = plot_survival_histograms(rows, "numThermals", tmp_path / "h.png")
    assert h.stat().st_size > 5000
    assert plot_trends(rows, ["numThermals"], tmp_path / "t.png").exists()
    with pytest.raises(ValueError, match="column"):
        plot_survival_histograms(rows, "migration", tmp_path / "x.png")
