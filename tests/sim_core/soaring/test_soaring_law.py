"""Law validation: clear errors naming the key (law files: tests/hil_bridge/files)."""

from __future__ import annotations

import pytest

from sim_core.config import ConfigError
from sim_core.soaring import Law


@pytest.mark.parametrize(
    ("data", "key"),
    [
        ({"cohesoin": 1.0}, "cohesoin"),
        ({"numAgents": 2.5}, "numAgents"),
        ({"dt": -0.5}, "dt"),
        ({"dt": 0.0}, "dt"),
        ({"totalTime": 7200.3}, "totalTime"),
        ({"bankMax": 1.6}, "bankMax"),
        ({"forwardSpeedMin": 0.0}, "forwardSpeedMin"),
        ({"controller": "boids"}, "controller"),
        ({"mapSize": [1, 2, 3]}, "mapSize"),
        ({"thermalSpeedMax": 1.0}, "thermalSpeedMax"),
        ({"cohesionAscensionMax": 0.1}, "cohesionAscensionMax"),
        ({"thermals": [{"x": 0, "y": 0, "radius": -1, "strength": 2}]}, "radius"),
        ({"thermals": [{"x": 0, "y": 0, "radius": 100, "strength": 2, "hot": 1}]}, "hot"),
        ({"agents": [{"x": 0, "y": 0}]}, "agents[0].z"),
        ({"agents": [{"x": 0, "y": 0, "z": 1000, "speed": 100}]}, "agents[0].speed"),
        ({"agents": [{"x": 0, "y": 0, "z": 1000}, {"x": 9, "y": 0, "z": -5}]}, "agents[1].z"),
        ({"agents": [{"x": 0, "y": 0, "z": 3000}]}, "agents[0].z"),
        ({"stopWhenDead": "yes"}, "stopWhenDead"),
    ],
    ids=lambda v: str(v)[:30],
)
def test_bad_values_name_the_key(data: dict[str, object], key: str) -> None:
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        Law.from_dict(data)


def test_defaults_are_the_seed_law() -> None:
    assert Law().steps == 14400 and Law().n_agents == 40


def test_round_trip_through_dict() -> None:
    law = Law().replace(thermals=[{"x": 1, "y": 2, "radius": 300, "strength": 4}],
                        agents=[{"x": 0, "y": 0, "z": 900}])
    assert Law.from_dict(law.to_dict()) == law
