"""``echoloop echo`` takes negative coordinates and angles as plain ``--option VALUE``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main as echoloop
from sim_core.sonar import Beam, synthesize
from tests.sim_core.sonar._scenes import cone_cloud


def test_negative_position_and_boresight(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    c, n, a = cone_cloud(300, seed=9)
    c = c - np.array([10.0, 0.0, 0.0])  # the cloud now lies in front of a sonar at x = -10
    leaves = tmp_path / "leaves.npz"
    np.savez(leaves, centers=c, normals=n, radii=a)
    out = tmp_path / "echo.npz"
    rc = echoloop(["echo", "--leaves", str(leaves), "--position", "-10,0,0", "--boresight",
                   "-0.5,-0", "--beamwidth", "30", "--out", str(out), "--json"])
    assert rc == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    beam = Beam.from_az_el([-10, 0, 0], np.radians(-0.5), 0.0, np.radians(30))
    expected = synthesize((c, n, a), beam)
    assert summary["leaves_in_beam"] == expected.leaves_in_beam > 0
    with np.load(out) as data:
        np.testing.assert_array_equal(data["echo"], expected.samples)
