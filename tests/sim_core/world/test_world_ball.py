"""The compiled ball test of the leaf gather: the k-d tree's set, in the leaves' order, with
blocks of leaves beyond the ball skipped by their boxes."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial import cKDTree

from sim_core.world.ball import BLOCK, ball_rows, block_bounds

coords = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


def _direct(centers: np.ndarray, point: np.ndarray, r: float) -> np.ndarray:
    """Every leaf tested, the sum in the module's order."""
    d2 = (centers[:, 0] - point[0]) ** 2 + (centers[:, 1] - point[1]) ** 2
    d2 += (centers[:, 2] - point[2]) ** 2
    return np.flatnonzero(d2 <= r * r)


def _rows(centers: np.ndarray, point: np.ndarray, r: float) -> np.ndarray:
    return ball_rows(centers, block_bounds(centers), point, r)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(0, 60), st.just(3)), elements=coords),
       arrays(np.float64, (3,), elements=coords), st.floats(0.0, 2e3))
def test_the_rows_are_the_kdtree_ball_in_order(centers: np.ndarray, point: np.ndarray,
                                               r: float) -> None:
    rows = _rows(centers, point, r)
    assert rows.dtype == np.intp
    np.testing.assert_array_equal(rows, _direct(centers, point, r))
    if centers.shape[0]:
        assert rows.tolist() == sorted(cKDTree(centers).query_ball_point(point, r))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12 * BLOCK), st.floats(0.0, 30.0),
       st.floats(0.01, 2.0))
def test_skipping_blocks_by_their_boxes_loses_no_leaf(seed: int, n: int, r: float,
                                                      step: float) -> None:
    """Leaves along random walks (compact runs, as a crown's branches store them), a ball
    anywhere around them: the rows are every leaf's own test, whatever blocks were skipped."""
    rng = np.random.default_rng(seed)
    centers = np.cumsum(rng.normal(0.0, step, (n, 3)), axis=0)
    point = centers[rng.integers(n)] + rng.normal(0.0, 10.0, 3)
    np.testing.assert_array_equal(_rows(centers, point, r), _direct(centers, point, r))


def test_leaves_on_the_sphere_are_in_and_just_beyond_are_out() -> None:
    r = 3.0
    on = np.array([[3.0, 0.0, 0.0], [0.0, -3.0, 0.0], [0.0, 0.0, 3.0]])
    beyond = np.nextafter(on, 2 * on)
    # each leaf alone in its block: the boxes are the leaves themselves
    spread = np.zeros((6 * BLOCK, 3)) + 1e6
    spread[::BLOCK] = np.vstack([on, beyond])
    assert _rows(spread, np.zeros(3), r).tolist() == [k * BLOCK for k in range(3)]
    assert _rows(np.zeros((0, 3)), np.zeros(3), r).shape == (0,)
    assert _rows(np.zeros((2, 3)), np.zeros(3), 0.0).tolist() == [0, 1]


def test_a_block_with_a_non_finite_centre_is_tested_leaf_by_leaf() -> None:
    centers = np.zeros((2 * BLOCK, 3))
    centers[:BLOCK] += 100.0  # a block far away, boxed
    centers[BLOCK + 1] = [np.nan, 0.0, 0.0]
    centers[BLOCK + 2] = [np.inf, 0.0, 0.0]
    bounds = block_bounds(centers)
    assert bounds.shape == (2, 2, 3) and np.isnan(bounds[1]).any()
    rows = ball_rows(centers, bounds, np.zeros(3), 1.0)
    expect = [BLOCK, *range(BLOCK + 3, 2 * BLOCK)]
    assert rows.tolist() == expect
