"""The compiled pre-cull keeps exactly the leaves its rules keep, with the values numpy computes
from the same expressions, at the extremes too (non-finite, zero normals, leaves on the sonar,
on the range and cone boundaries)."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from sim_core.sonar.precull import precull

SPECIAL = st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1e300, np.inf, -np.inf, np.nan, 2.0])
COORD = st.one_of(st.floats(-20.0, 20.0), SPECIAL)


def _numpy(c: np.ndarray, n: np.ndarray, a: np.ndarray, pos: np.ndarray, axis: np.ndarray,
           r_min2: float, reach2: float, cone: bool, cos_reach: float) -> tuple[Any, ...]:
    with np.errstate(all="ignore"):
        d = c - pos
        r2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        nn2 = n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2]
        finite = np.isfinite(d[:, 0] + d[:, 1] + d[:, 2] + (n[:, 0] + n[:, 1] + n[:, 2]) + a)
        valid = (nn2 > 0.0) & (r2 >= r_min2) & finite
        r = np.sqrt(r2)
        proj = d[:, 0] * axis[0] + d[:, 1] * axis[1] + d[:, 2] * axis[2]
        keep = valid & (r2 <= reach2)
        if cone:
            keep &= proj >= cos_reach * r
        nd = (n[:, 0] * d[:, 0] + n[:, 1] * d[:, 1] + n[:, 2] * d[:, 2]) / np.sqrt(nn2)
    rows = np.flatnonzero(keep)
    return rows, r[rows], proj[rows], d[rows], nd[rows], int((~valid).sum())


@settings(max_examples=200, deadline=None)
@given(c=arrays(np.float64, (40, 3), elements=COORD), n=arrays(np.float64, (40, 3), elements=COORD),
       a=arrays(np.float64, 40, elements=st.one_of(st.floats(0.0, 0.1), SPECIAL)),
       cone=st.booleans(), cos_reach=st.floats(-1.0, 1.0), reach=st.floats(0.0, 30.0),
       subset=st.booleans())
def test_the_compiled_precull_keeps_what_its_rules_keep(
    c: np.ndarray, n: np.ndarray, a: np.ndarray, cone: bool, cos_reach: float, reach: float,
    subset: bool,
) -> None:
    pos = np.array([1.0, -2.0, 0.5])
    axis = np.array([0.6, 0.8, 0.0])
    r_min2 = 0.01
    rows_in = np.arange(0, 40, 3, dtype=np.intp) if subset else None
    m = 40 if rows_in is None else rows_in.shape[0]
    out = (np.empty(m, np.intp), np.empty(m), np.empty(m), np.empty((m, 3)), np.empty(m))
    found, dropped = precull(c, n, a, rows_in, pos, axis, r_min2=r_min2, reach2=reach * reach,
                             cone=cone, cos_reach=cos_reach, out=out)
    sub = np.arange(40) if rows_in is None else rows_in
    rows, r, proj, d, nd, gone = _numpy(c[sub], n[sub], a[sub], pos, axis, r_min2, reach * reach,
                                        cone, cos_reach)
    assert (found, dropped) == (rows.shape[0], gone)
    np.testing.assert_array_equal(out[0][:found], sub[rows])
    for got, want in zip(out[1:], (r, proj, d, nd), strict=True):
        np.testing.assert_array_equal(got[:found], want)  # the same bits, NaN where numpy's
