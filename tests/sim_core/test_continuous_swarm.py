"""The seed law flown in continuous time (sim_core.continuous_swarm) and `swarm run --physics`:
the controller keeps its rate, commands are held between decisions, the seed's rules stay."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main
from sim_core.continuous_swarm import ContinuousSwarm, run_continuous
from sim_core.flight import BANK, SPEED, FlightParams, Z
from sim_core.soaring import Commands, Law, run


def _glide_law(**extra: object) -> Law:
    """One glider, no thermals, every Boids gain zero (the seed's glide_a case)."""
    base: dict[str, object] = {
        "totalTime": 120.0, "numThermals": 0, "cohesion": 0.0, "separation": 0.0,
        "alignment": 0.0, "migration": 0.0,
        "agents": [{"x": 0.0, "y": 0.0, "z": 1500.0, "heading": 0.3, "speed": 10.0}],
    }
    return Law().replace(**{**base, **extra})


def test_pure_glide_is_the_seed_step_and_the_closed_form(data_dir: Path) -> None:
    law = _glide_law()
    cont = run_continuous(law, physics_rate_hz=20.0, trace=True)[0]
    disc = run(law, trace=True)
    assert cont.trace is not None and disc.trace is not None
    t = cont.trace.t
    np.testing.assert_allclose(t, np.arange(len(t)) * law.dt)
    sink = law.Sink_A * 100.0 + law.Sink_B * 10.0 + law.Sink_C
    np.testing.assert_allclose(cont.trace.z[:, 0], 1500.0 + sink * t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(cont.trace.x[:, 0], 10.0 * math.cos(0.3) * t, atol=1e-9)
    # a straight glide at constant speed: the seed's Euler step is exact too
    np.testing.assert_allclose(disc.trace.z[: len(t), 0], cont.trace.z[:, 0], atol=1e-9)
    assert cont.metrics.flightTime == disc.metrics.flightTime == 120.0


def test_commands_are_held_between_decisions_at_any_integration_split() -> None:
    law = Law().replace(totalTime=30.0, numAgents=6, dt=0.5)
    a = ContinuousSwarm(law, seed=5)
    b = ContinuousSwarm(law, seed=5)
    for _ in range(8):
        a.decide()
        b.decide()
        a.advance(0.5, substeps=10)  # one control period at once (swarm run) ...
        for _ in range(10):
            b.advance(0.05)  # ... or tick by tick at 20 Hz (the server)
        np.testing.assert_array_equal(a.flight_state, b.flight_state)
    assert a.step_count == 8
    # the bank moved continuously towards commands that stay fixed within a period
    assert np.all(np.abs(a.flight_state[BANK]) <= law.bankMax + 1e-12)


def test_same_seed_same_flight_other_seed_differs_and_batch_equals_alone() -> None:
    law = Law().replace(totalTime=40.0, numAgents=8)
    one = run_continuous(law, seeds=[3], physics_rate_hz=10.0)[0]
    again = run_continuous(law, seeds=[3], physics_rate_hz=10.0)[0]
    other = run_continuous(law, seeds=[4], physics_rate_hz=10.0)[0]
    both = run_continuous(law, seeds=[3, 4], physics_rate_hz=10.0)
    assert one.metrics == again.metrics
    assert one.metrics != other.metrics
    assert both[0].metrics == one.metrics and both[1].metrics == other.metrics
    assert [r.seed for r in both] == [3, 4]


def test_ground_deaths_and_all_dead_stop_the_run() -> None:
    law = _glide_law(totalTime=600.0, agents=[
        {"x": 0.0, "y": 0.0, "z": 20.0, "heading": 0.0, "speed": 10.0},
        {"x": 500.0, "y": 0.0, "z": 40.0, "heading": 0.0, "speed": 10.0}])
    res = run_continuous(law, physics_rate_hz=10.0)[0]
    assert res.metrics.groundDeaths == 2 and res.metrics.surviving == 0
    sink = -(law.Sink_A * 100 + law.Sink_B * 10 + law.Sink_C)
    # as in the seed, a glider dies at the step whose flight reaches the ground: the higher
    # one after 40 / sink s; each flew every step before its last
    k20, k40 = (math.ceil(h / sink / law.dt) for h in (20.0, 40.0))
    assert res.steps == k40
    assert res.metrics.flightTime == pytest.approx((k20 - 1 + k40 - 1) * law.dt)


def test_an_external_command_is_flown_instead_of_the_law() -> None:
    law = Law().replace(totalTime=60.0, numAgents=3)
    swarm = ContinuousSwarm(law, seed=1, flight=FlightParams(bank_tau_s=0.2))
    ext = Commands(bank_cmd=np.array([[0.2, 0.0, 0.0]]), airspeed_cmd=np.array([[12.0, 0, 0]]),
                   mask=np.array([[True, False, False]]))
    v0 = swarm.flight_state[SPEED, 0, 0]
    for _ in range(20):
        swarm.decide(ext)
        swarm.advance(0.5, substeps=5, external=ext)
    y = swarm.flight_state
    assert y[BANK, 0, 0] == pytest.approx(0.2, abs=1e-9)
    # |12 - v0| <= 4 m/s stays below the rate limit's reach (5 s * 1 m/s^2): a pure lag
    assert y[SPEED, 0, 0] == pytest.approx(12.0 - (12.0 - v0) * math.exp(-10.0 / 5.0), abs=1e-6)
    out = swarm.outputs(ext)
    assert out.roll[0, 0] == pytest.approx(-0.2, abs=1e-9)
    with pytest.raises(ValueError, match="glide"):
        ContinuousSwarm(law, flight=FlightParams(vertical="hold"))


def test_swarm_run_cli_physics_choice(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    base = ["swarm", "run", "--law", "default", "--set", "totalTime=30", "--set",
            "numAgents=5", "--seed", "3", "--json"]
    assert main(base) == 0
    discrete = json.loads(capsys.readouterr().out)
    assert main([*base, "--physics", "discrete"]) == 0
    assert json.loads(capsys.readouterr().out)["heightScore"] == discrete["heightScore"]
    npz = tmp_path / "c.npz"
    assert main([*base, "--physics", "continuous", "--physics-rate", "20", "--flight",
                 "bank_tau_s=0.5", "--trace", str(npz)]) == 0
    cont = json.loads(capsys.readouterr().out)
    law = Law().replace(totalTime=30.0, numAgents=5)
    want = run_continuous(law, seeds=[3], physics_rate_hz=20.0,
                          flight=FlightParams(bank_tau_s=0.5))[0].metrics
    assert cont["heightScore"] == want.heightScore != discrete["heightScore"]
    assert np.load(npz)["z"].shape == (60, 5)
    assert main([*base, "--physics", "continuous", "--flight", "bank_tau=1"]) == 1
    assert "bank_tau" in capsys.readouterr().err
    assert main([*base, "--flight", "bank_tau_s=1"]) == 1


def test_flown_state_keeps_its_height_limits() -> None:
    law = Law().replace(totalTime=20.0, numAgents=4, agentSpawnAltiRange=[2590.0, 2599.0],
                        thermals=[{"x": 0.0, "y": 0.0, "radius": 6000.0, "strength": 5.0}])
    swarm = ContinuousSwarm(law, seed=0)
    for _ in range(20):
        swarm.decide()
        swarm.advance(0.5, substeps=5)
    assert np.all(swarm.flight_state[Z] <= law.agentCeiling)
