"""Leaves: struct-of-arrays contract, npz round trip, range and cone queries against brute force."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_core.world import Leaves
from sim_core.world.leaves import BYTES_PER_LEAF


def _random_leaves(n: int, seed: int = 0) -> Leaves:
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Leaves(
        rng.uniform(-10, 10, (n, 3)), normals, rng.uniform(0.01, 0.04, n), rng.integers(0, 5, n)
    )


def test_storage_is_60_bytes_per_leaf_and_kdtree_is_lazy() -> None:
    leaves = _random_leaves(1000)
    assert BYTES_PER_LEAF == 60
    assert leaves.nbytes == 60 * 1000
    assert leaves.centers.dtype == np.float64 and leaves.tree_id.dtype == np.int32
    leaves.query_ball(np.zeros(3), 1.0)
    assert leaves.nbytes > 60 * 1000  # the k-d tree now counts


def test_shape_validation_names_the_array() -> None:
    with pytest.raises(ValueError, match="normals"):
        Leaves(np.zeros((3, 3)), np.zeros((2, 3)), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="centers"):
        Leaves(np.zeros((3, 2)), np.zeros((3, 3)), np.zeros(3), np.zeros(3))


def test_empty_concat_select() -> None:
    a, b = _random_leaves(10, 1), _random_leaves(5, 2)
    both = Leaves.concat([a, b])
    assert len(both) == 15 and len(Leaves.empty()) == 0 and len(Leaves.concat([])) == 0
    assert both.select(np.arange(10, 15)) == b
    mask = np.zeros(15, dtype=bool)
    mask[:10] = True
    assert both.select(mask) == a
    with pytest.raises(ValueError, match="mask"):
        both.select(np.ones(3, dtype=bool))


@settings(max_examples=40, deadline=None)
@given(
    px=st.floats(-12, 12), py=st.floats(-12, 12), pz=st.floats(-12, 12),
    r=st.floats(0, 15), ax=st.floats(-1, 1), ay=st.floats(-1, 1), az=st.floats(-1, 1),
    half=st.floats(0, np.pi),
)
def test_queries_match_brute_force(
    px: float, py: float, pz: float, r: float, ax: float, ay: float, az: float, half: float
) -> None:
    leaves = _random_leaves(400, 3)
    p = np.array([px, py, pz])
    d = leaves.centers - p
    dist = np.linalg.norm(d, axis=1)
    ball = leaves.query_ball(p, r)
    assert np.array_equal(ball, np.flatnonzero(dist <= r))
    axis = np.array([ax, ay, az])
    if np.linalg.norm(axis) < 1e-3:
        with pytest.raises(ValueError, match="axis"):
            leaves.query_cone(p, np.zeros(3), half, r)
        return
    cone = leaves.query_cone(p, axis, half, r)
    cosang = (d @ axis) / np.linalg.norm(axis) / np.where(dist > 0, dist, 1)
    expect = np.flatnonzero((dist <= r) & (cosang >= np.cos(half)))
    # angles within float rounding of the boundary may go either way
    edge = np.abs(cosang - np.cos(half)) < 1e-12
    assert set(cone) ^ set(expect) <= set(np.flatnonzero(edge))


def test_query_input_errors() -> None:
    leaves = _random_leaves(5)
    with pytest.raises(ValueError, match="point"):
        leaves.query_ball(np.zeros(2), 1.0)
    with pytest.raises(ValueError, match="r must"):
        leaves.query_ball(np.zeros(3), -1.0)
    with pytest.raises(ValueError, match="half_angle"):
        leaves.query_cone(np.zeros(3), np.ones(3), 4.0, 1.0)
    assert Leaves.empty().query_ball(np.zeros(3), 5.0).size == 0
