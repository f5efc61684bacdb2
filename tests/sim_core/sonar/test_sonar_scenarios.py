"""Seed 000 scenarios: the "8" route, scene builders, the scenario CLI, and baseband IQ."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main as echoloop
from sim_core.sonar import Beam, synthesize, to_baseband
from sim_core.sonar.baseband import from_baseband
from sim_core.sonar.scenarios import (
    TABLE1_SEED_SECONDS,
    fig6_scene,
    figure_eight_path,
    maple_cluster,
    table1_setups,
)
from tests.sim_core.sonar._scenes import FS, cone_cloud, rel_l2


def test_figure_eight_lies_on_the_lemniscate_with_tangent_headings() -> None:
    pos, heading = figure_eight_path((3.0, -2.0), 10.0, 4.0, 7.5, 40)
    x, y = pos[:, 0] - 3.0, pos[:, 1] + 2.0
    # Gerono: (y / W)^2 = (x / L)^2 (1 - (x / L)^2)
    np.testing.assert_allclose((y / 4.0) ** 2, (x / 10.0) ** 2 * (1 - (x / 10.0) ** 2), atol=1e-12)
    assert np.all(pos[:, 2] == 7.5)
    step = np.diff(pos[:, :2], axis=0)
    mid_heading = np.arctan2(step[:, 1], step[:, 0])
    mean = np.angle(np.exp(1j * heading[:-1]) + np.exp(1j * heading[1:]))
    err = np.angle(np.exp(1j * (mid_heading - mean)))
    assert np.abs(err).max() < 0.25
    assert len({tuple(p) for p in np.round(pos, 9)}) == 40
    rot, _ = figure_eight_path((0.0, 0.0), 10.0, 4.0, 0.0, 8, rotation_rad=math.pi / 2)
    base, _ = figure_eight_path((0.0, 0.0), 10.0, 4.0, 0.0, 8)
    np.testing.assert_allclose(rot[:, 0], -base[:, 1], atol=1e-12)
    with pytest.raises(ValueError, match="count"):
        figure_eight_path((0.0, 0.0), 1.0, 1.0, 0.0, 0)


def test_fig6_more_beamwidth_more_leaves_in_beam() -> None:
    leaves, pings = fig6_scene(seed=0)
    counts = [synthesize(leaves, p.beam).leaves_in_beam for p in pings]
    assert [round(math.degrees(p.beam.beamwidth_rad)) for p in pings] == [10, 30, 50]
    assert 0 < counts[0] < counts[1] < counts[2]


def test_table1_setups_shape_and_published_numbers() -> None:
    forest = maple_cluster(2, seed=0)
    setups = table1_setups(forest)
    assert {k: len(v) for k, v in setups["circular"].items()} == {1: 1, 5: 5, 10: 10, 15: 15}
    assert sorted(setups["fixed"]) == [10, 20, 30, 40, 50]
    assert TABLE1_SEED_SECONDS["circular"][15] == (1.03, 1.68, 1.92, 2.54, 3.03)
    assert TABLE1_SEED_SECONDS["fixed"][50][-1] == 1.63
    ring = np.array([p.beam.position for p in setups["circular"][15]])
    centre = ring[:, :2].mean(axis=0)
    dist = np.linalg.norm(ring[:, :2] - centre, axis=1)
    np.testing.assert_allclose(dist, dist[0], rtol=1e-9)
    assert np.all(ring[:, 2] == 5.0)


def test_scenario_cli_fig6_writes_png_and_json(tmp_path: Path, capsys) -> None:
    assert echoloop(["scenario", "fig6", "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [p["beamwidth_deg"] for p in result["pings"]] == [10.0, 30.0, 50.0]
    assert (tmp_path / "fig6.png").stat().st_size > 10_000


def test_baseband_iq_reconstructs_the_band_exactly_and_measures_out_of_band_loss() -> None:
    beam = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(30.0))
    # the reference echo is band-limited to rounding (fast's float32 transform leaves ~1e-7)
    echo = synthesize(cone_cloud(500, seed=1), beam, fidelity="reference").samples
    for decimation, tol in ((1, 1e-12), (4, 1e-12), (16, 1e-12), (20, 1e-8)):
        iq, fs_out = to_baseband(echo, FS, 70e3, decimation)
        assert fs_out == FS / decimation and iq.shape == (echo.shape[0] // decimation,)
        back = from_baseband(iq, fs_out, 70e3, decimation, echo.shape[0])
        # 60-80 kHz fits in 70 kHz +- 12.5 kHz; at 20 the 80 kHz bin (Hann weight ~3e-5) is lost
        assert rel_l2(back, echo) < tol
    iq, fs_out = to_baseband(echo, FS, 70e3, 40)  # +-5 kHz keeps only 65-75 kHz
    spec = np.fft.rfft(echo)
    f = np.fft.rfftfreq(echo.shape[0], 1 / FS)
    kept = np.where(np.abs(f - 70e3) < 5e3, spec, 0)
    expected = np.linalg.norm(np.fft.irfft(spec - kept, n=24000)) / np.linalg.norm(echo)
    back = from_baseband(iq, fs_out, 70e3, 40, echo.shape[0])
    assert rel_l2(back, echo) == pytest.approx(expected, rel=1e-2)
    with pytest.raises(ValueError, match="decimation"):
        to_baseband(echo, FS, 70e3, 0)
    iq7, fs7 = to_baseband(echo, FS, 70e3, 7)  # any decimation: ceil(N / 7) samples
    iq1, _ = to_baseband(echo, FS, 70e3, 1)
    assert iq7.shape == (math.ceil(24000 / 7),) and fs7 == FS / 7
    np.testing.assert_allclose(iq7, iq1[::7], atol=1e-15)
    with pytest.raises(ValueError, match="dividing"):
        from_baseband(iq7, fs7, 70e3, 7, 24000)
    with pytest.raises(ValueError, match="f_center"):
        to_baseband(echo, FS, 300e3, 4)
