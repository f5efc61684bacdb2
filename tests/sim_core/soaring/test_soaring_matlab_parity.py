"""`echoloop swarm run` (the seed's discrete step, its default) against the seed's own MATLAB
traces in tests/data/seed002_matlab (see the README there for what was run and measured)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main
from sim_core.soaring import Trace

#: case -> (position tolerance m, angle/speed tolerance): glide and thermal crossing are exact
#: to the last bit on any SIMD path; swarm5 drifts to ~1e-7 m over 6638 steps (README)
CASES = {"glide_a": (1e-9, 1e-12), "thermal_cross": (1e-9, 1e-12), "swarm5": (1e-6, 1e-8)}
COLUMNS = (("x", "xData", 0), ("y", "yData", 0), ("z", "zData", 0), ("heading", "headingData", 1),
           ("bank", "bankAngleData", 1), ("airspeed", "fVelData", 1))


@pytest.mark.parametrize("case", sorted(CASES))
def test_swarm_run_matches_the_seed_matlab_trace(
    case: str, data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    law = data_dir / "seed002_matlab" / f"{case}.yaml"
    npz = tmp_path / f"{case}.npz"
    assert main(["swarm", "run", "--law", str(law), "--trace", str(npz), "--json"]) == 0
    metrics = json.loads(capsys.readouterr().out)
    trace = Trace.load_npz(npz)
    with np.load(data_dir / "seed002_matlab" / f"{case}_matlab.npz") as ref:
        alive = ref["aliveData"]
        steps = alive.shape[1]  # the run stops when every glider is dead
        assert trace.n_steps == steps + 1  # the initial state, then one row per step
        for ours, theirs, kind in COLUMNS:
            a = getattr(trace, ours)[1:].T
            np.testing.assert_allclose(a, ref[theirs][:, :steps], rtol=0,
                                       atol=CASES[case][kind], err_msg=f"{case}.{ours}")
        np.testing.assert_array_equal(trace.alive[1:].T, alive != 0)
        for key in ("surviving", "collisionDeaths", "groundDeaths", "flightTime",
                    "thermalUseScore"):
            assert metrics[key] == float(ref[key]), key
        assert metrics["survivingPercent"] == pytest.approx(100.0 * float(ref["survivingPercent"]))
        assert metrics["heightScore"] == pytest.approx(float(ref["heightScore"]), rel=1e-9)
