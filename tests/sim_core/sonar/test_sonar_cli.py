"""``echoloop echo`` contract (issue 3): options, outputs, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main as echoloop
from sim_core.sonar import Beam, EchoParams, synthesize
from tests.sim_core.sonar._scenes import cone_cloud


@pytest.fixture
def leaves_file(tmp_path: Path) -> Path:
    c, n, a = cone_cloud(400, seed=5)
    c[0] = np.nan
    n[1] = 0.0
    path = tmp_path / "leaves.npz"
    np.savez(path, centers=c, normals=n, radii=a, tree_id=np.zeros(400, dtype=np.int32))
    return path


def test_echo_json_out_and_plot(leaves_file: Path, tmp_path: Path, capsys) -> None:
    out, png = tmp_path / "echo.npz", tmp_path / "echo.png"
    rc = echoloop(["echo", "--leaves", str(leaves_file), "--position", "0,0,0", "--boresight",
                   "0,0", "--beamwidth", "30", "--fidelity", "reference", "--out", str(out),
                   "--plot", str(png), "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert {"leaves_in_beam", "fidelity", "samples", "fs", "seconds"} <= set(summary)
    assert summary["fidelity"] == "reference" and summary["samples"] == 24000
    assert summary["fs"] == 400e3 and summary["dropped"] == 2
    with np.load(out) as data:
        echo, fs = data["echo"], float(data["fs"])
    assert echo.shape == (24000,) and echo.dtype == np.float64 and fs == 400e3
    c, n, a = cone_cloud(400, seed=5)
    expected = synthesize((c[2:], n[2:], a[2:]), Beam([0, 0, 0], [1, 0, 0], np.radians(30)),
                          fidelity="reference")
    np.testing.assert_allclose(echo, expected.samples, rtol=0, atol=1e-12)
    assert summary["leaves_in_beam"] == expected.leaves_in_beam
    assert png.stat().st_size > 1000


def test_echo_azimuth_elevation_and_no_spreading(leaves_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "e.npz"
    rc = echoloop(["echo", "--leaves", str(leaves_file), "--position", "1,2,3", "--boresight",
                   "90,-10", "--beamwidth", "40", "--no-spreading", "--samples", "24000",
                   "--out", str(out)])
    assert rc == 0
    with np.load(leaves_file) as d:
        c, n, a = d["centers"], d["normals"], d["radii"]
    beam = Beam.from_az_el([1, 2, 3], np.radians(90), np.radians(-10), np.radians(40))
    np.testing.assert_allclose(beam.boresight, [0.0, np.cos(np.radians(10)),
                                                -np.sin(np.radians(10))], atol=1e-15)
    ref = synthesize((c, n, a), beam, EchoParams(spreading=False))
    with np.load(out) as data:
        np.testing.assert_array_equal(data["echo"], ref.samples)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--beamwidth", "0"], "beamwidth"),
        (["--beamwidth", "180"], "beamwidth"),
        (["--position", "0,nan,0"], "position"),
        (["--position", "0,0"], "position"),
        (["--boresight", "a,b"], "boresight"),
        (["--samples", "12000"], "cannot hold the farthest kept leaf"),
        (["--samples", "24001"], "not a multiple of the bin spacing"),
    ],
    ids=["bw0", "bw180", "nan-position", "short-position", "bad-boresight", "short-window",
         "off-bin"],
)
def test_echo_invalid_input_exits_non_zero_with_message(
    leaves_file: Path, args: list[str], message: str, capsys
) -> None:
    base = {"--position": "0,0,0", "--boresight": "0,0", "--beamwidth": "20"}
    for i in range(0, len(args), 2):
        base[args[i]] = args[i + 1]
    argv = ["echo", "--leaves", str(leaves_file)] + [x for kv in base.items() for x in kv]
    assert echoloop(argv) == 1
    assert message in capsys.readouterr().err


def test_echo_rejects_a_file_without_leaf_arrays(tmp_path: Path, capsys) -> None:
    path = tmp_path / "bad.npz"
    np.savez(path, points=np.zeros((3, 3)))
    rc = echoloop(["echo", "--leaves", str(path), "--position", "0,0,0", "--boresight", "0,0",
                   "--beamwidth", "20"])
    assert rc == 1 and "centers" in capsys.readouterr().err
