"""hil_bridge.files.config: YAML files and KEY=VALUE overrides."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil_bridge.files.config import load_yaml, parse_override
from sim_core.config import ConfigError


def test_load_yaml_reports_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("a: 1\nb: [1, 2\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:\d+: invalid YAML"):
        load_yaml(p)
    with pytest.raises(ConfigError, match="cannot read"):
        load_yaml(tmp_path / "missing.yaml")


@given(st.one_of(st.integers(), st.booleans(), st.text(alphabet="abc", min_size=1)))
def test_parse_override_yaml_values(value: object) -> None:
    text = f"k={str(value).lower() if isinstance(value, bool) else value}"
    key, parsed = parse_override(text)
    assert key == "k"
    assert parsed == value


def test_parse_override_errors() -> None:
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_override("novalue")
    assert parse_override("x=1e-3") == ("x", 1e-3)
