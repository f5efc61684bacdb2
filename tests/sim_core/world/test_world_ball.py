"""The compiled ball test of the leaf gather: the k-d tree's set, in the leaves' order."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial import cKDTree

from sim_core.world.ball import ball_mask

coords = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(0, 60), st.just(3)), elements=coords),
       arrays(np.float64, (3,), elements=coords), st.floats(0.0, 2e3))
def test_the_mask_is_the_kdtree_ball_in_order(centers: np.ndarray, point: np.ndarray,
                                             r: float) -> None:
    mask = ball_mask(centers, point, r)
    assert mask.dtype == np.bool_ and mask.shape == (centers.shape[0],)
    expect = (centers[:, 0] - point[0]) ** 2 + (centers[:, 1] - point[1]) ** 2
    expect += (centers[:, 2] - point[2]) ** 2
    np.testing.assert_array_equal(mask, expect <= r * r)
    if centers.shape[0]:
        hits = sorted(cKDTree(centers).query_ball_point(point, r))
        assert np.flatnonzero(mask).tolist() == hits


def test_leaves_on_the_sphere_are_in_and_just_beyond_are_out() -> None:
    r = 3.0
    on = np.array([[3.0, 0.0, 0.0], [0.0, -3.0, 0.0], [0.0, 0.0, 3.0]])
    beyond = np.nextafter(on, 2 * on)
    mask = ball_mask(np.vstack([on, beyond]), np.zeros(3), r)
    assert mask.tolist() == [True] * 3 + [False] * 3
    assert ball_mask(np.zeros((0, 3)), np.zeros(3), r).shape == (0,)
    assert ball_mask(np.zeros((2, 3)), np.zeros(3), 0.0).tolist() == [True, True]
