"""sim_core.rng: determinism, independence of keyed streams, input checks."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_core.rng import derive_rng, derive_seed_sequence, make_rng, spawn


def test_same_seed_bit_identical() -> None:
    a = make_rng(7).standard_normal(1000)
    b = make_rng(7).standard_normal(1000)
    assert np.array_equal(a, b)


def test_different_seed_differs() -> None:
    assert not np.array_equal(make_rng(7).random(10), make_rng(8).random(10))


@given(seed=st.integers(0, 2**63), key=st.lists(st.integers(0, 2**31), max_size=4))
def test_derived_stream_reproducible(seed: int, key: list[int]) -> None:
    assert derive_rng(seed, *key).integers(0, 2**62) == derive_rng(seed, *key).integers(0, 2**62)


def test_keyed_streams_are_independent_of_siblings() -> None:
    # the stream of tree 3 must not depend on how many trees came before it
    tree3 = derive_rng(11, "forest", 0, 3).random(5)
    _ = [derive_rng(11, "forest", 0, i).random(100) for i in range(10)]
    assert np.array_equal(tree3, derive_rng(11, "forest", 0, 3).random(5))
    assert not np.array_equal(tree3, derive_rng(11, "forest", 0, 4).random(5))
    assert not np.array_equal(tree3, derive_rng(11, "forest", 1, 3).random(5))


def test_string_keys_are_stable() -> None:
    assert derive_seed_sequence(5, "sonar").spawn_key == (zlib.crc32(b"sonar"),)
    assert derive_rng(5, "sonar").random() == derive_rng(5, "sonar").random()
    assert derive_rng(5, "sonar").random() != derive_rng(5, "boids").random()


def test_seed_sequence_input_extends_key() -> None:
    parent = np.random.SeedSequence(3)
    assert derive_rng(parent, 1).random() == derive_rng(3, 1).random()


@pytest.mark.parametrize("bad", [-1, 1.5, "3", True])
def test_bad_seed_rejected(bad: object) -> None:
    with pytest.raises((TypeError, ValueError), match="seed"):
        make_rng(bad)  # type: ignore[arg-type]


def test_bad_key_rejected() -> None:
    with pytest.raises(ValueError, match="non-negative"):
        derive_rng(1, -2)
    with pytest.raises(TypeError, match="key"):
        derive_rng(1, 2.0)  # type: ignore[arg-type]


def test_spawn() -> None:
    kids = spawn(make_rng(1), 3)
    assert len(kids) == 3
    assert len({k.random() for k in kids}) == 3
    with pytest.raises(ValueError):
        spawn(make_rng(1), -1)
