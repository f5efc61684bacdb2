"""Law loading and validation: clear errors naming the key, at load."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim_core.config import ConfigError
from sim_core.soaring import Law, default_law_path


def test_packaged_default_is_the_seed_law(data_dir: Path) -> None:
    assert Law.from_yaml("default") == Law()
    assert Law.from_yaml(data_dir / "seed002" / "law_40survivors.yaml") == Law()
    assert default_law_path().read_text() == (
        data_dir / "seed002" / "law_40survivors.yaml"
    ).read_text()
    assert Law().steps == 14400 and Law().n_agents == 40


def test_overrides_take_precedence(tmp_path: Path) -> None:
    p = tmp_path / "law.yaml"
    p.write_text("numAgents: 20\ncohesion: 3000\n")
    law = Law.from_yaml(p, {"cohesion": 1e4, "controller": "baseline"})
    assert law.numAgents == 20 and law.cohesion == 1e4 and law.controller == "baseline"
    assert law.separation == Law().separation


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


def test_bad_file_is_named(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("dt: -1\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*dt"):
        Law.from_yaml(p)
    p.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        Law.from_yaml(p)
    with pytest.raises(ConfigError, match="cannot read"):
        Law.from_yaml(tmp_path / "missing.yaml")


def test_round_trip_through_dict() -> None:
    law = Law().replace(thermals=[{"x": 1, "y": 2, "radius": 300, "strength": 4}],
                        agents=[{"x": 0, "y": 0, "z": 900}])
    assert Law.from_dict(law.to_dict()) == law
