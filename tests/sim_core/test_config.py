"""sim_core.config: frozen dataclasses from plain data, strict keys and types."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from sim_core.config import ConfigError, apply_overrides, from_dict


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0
    name: str = "x"


@dataclass(frozen=True)
class Outer:
    count: int
    mode: Literal["fast", "lockstep"] = "fast"
    inner: Inner = field(default_factory=Inner)
    points: tuple[float, ...] = ()
    pair: tuple[int, str] | None = None
    tags: dict[str, int] = field(default_factory=dict)
    items: list[Inner] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError(f"count must be >= 0, got {self.count}")


def test_builds_nested() -> None:
    o = from_dict(
        Outer,
        {"count": 2, "inner": {"gain": 3}, "points": [1, 2.5], "pair": [1, "a"],
         "tags": {"a": 1}, "items": [{"name": "y"}]},
    )
    assert o == Outer(2, "fast", Inner(3.0, "x"), (1.0, 2.5), (1, "a"), {"a": 1}, [Inner(name="y")])
    assert isinstance(o.inner.gain, float)


def test_unknown_key_names_key_and_expected() -> None:
    with pytest.raises(ConfigError, match=r"inner: unknown key\(s\) \['gian'\].*gain"):
        from_dict(Outer, {"count": 1, "inner": {"gian": 2}})


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"count": "3"}, r"count: expected an integer"),
        ({"count": True}, r"count: expected an integer"),
        ({"count": 1, "mode": "slow"}, r"mode: expected one of \['fast', 'lockstep'\]"),
        ({"count": 1, "points": [1, "a"]}, r"points\[1\]: expected a number"),
        ({"count": 1, "inner": {"gain": float("nan")}}, r"inner.gain: expected a finite number"),
        ({"count": 1, "pair": [1]}, r"pair: expected"),
        ({}, r"count: required key is missing"),
        ({"count": -1}, r"count must be >= 0"),
        ([1, 2], r"expected a mapping"),
    ],
)
def test_bad_values(data: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        from_dict(Outer, data)


def test_config_error_is_value_error() -> None:
    assert issubclass(ConfigError, ValueError)


def test_overrides() -> None:
    base = {"a": {"b": 1}, "c": 2}
    out = apply_overrides(base, {"a.b": 5, "a.d.e": [1], "c": 3})
    assert out == {"a": {"b": 5, "d": {"e": [1]}}, "c": 3}
    assert base == {"a": {"b": 1}, "c": 2}
    with pytest.raises(ConfigError, match="not a mapping"):
        apply_overrides({"c": 2}, {"c.x": 1})
