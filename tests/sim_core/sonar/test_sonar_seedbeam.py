"""The seed's 1° beam grid (sim_core.sonar.seedbeam): node placement, wrap, rounding, edges.

Expected node offsets are worked by hand from ``filter_leaves_beamG.m`` (docs/spec/
seed_models.md §1.3): nodes at whole degrees from the beam centre, azimuth moved by ±2 pi by
the seed's rule first, elevations past the grid's ends clamped to the end node. The same
choices were checked against the seed's own function run under GNU Octave 7.3 (16,000 leaves
in 40 beams, including these edges: every node equal).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_core.sonar import Beam, Ear, EchoParams, synthesize
from sim_core.sonar.seedbeam import nearest_node, octave_linspace, off_axis

D = math.radians


def unit(az_deg: float, el_deg: float) -> np.ndarray:
    a, e = D(az_deg), D(el_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def node_offsets(axis: np.ndarray, leaves_deg: list[tuple[float, float]],
                 lookup: str = "grid") -> np.ndarray:
    """(Δaz, Δel) in degrees of leaves given as (az, el) degrees, shape (M, 2)."""
    d = np.stack([unit(a, e) * 3.0 for a, e in leaves_deg])
    daz, dele = off_axis(d[:, 0], d[:, 1], d[:, 2], axis, lookup)
    return np.degrees(np.stack([daz, dele], axis=1))


def test_octave_linspace_is_octave_bit_for_bit() -> None:
    """Values printed by Octave 7.3 (%.17g) where numpy's linspace differs in the last bit."""
    az = octave_linspace(0.3 - math.pi, 0.3 + math.pi, 361)
    assert az[0] == 0.3 - math.pi and az[-1] == 0.3 + math.pi
    assert az[180] == 0.29999999999999982  # the middle, (x1 + x2)/2
    assert az[299] == 2.376941809873252 != np.linspace(0.3 - math.pi, 0.3 + math.pi, 361)[299]
    assert az[359] == 3.4241393610698498
    el = octave_linspace(-1.2 - math.pi / 2, -1.2 + math.pi / 2, 181)
    assert el[1] == -2.7533430342749536 and el[90] == -1.2000000000000002
    assert el[179] == 0.35334303427495328
    assert octave_linspace(-math.pi, math.pi, 361)[180] == 0.0
    np.testing.assert_allclose(np.diff(az), D(1.0), rtol=1e-12)


def test_nearest_node_takes_the_first_of_two_and_clamps_at_the_ends() -> None:
    nodes = np.array([0.0, 1.0, 2.0, 3.0])
    got = nearest_node(np.array([0.5, 1.5, 2.49, 2.51, -7.0, 9.0, 3.0]), nodes)
    np.testing.assert_array_equal(got, [0, 1, 2, 3, 0, 3, 3])


@pytest.mark.parametrize(
    ("centre", "leaves", "expected"),
    [
        # beam just left of +180°: leaves across the seam gain 2 pi
        ((179.7, 0.0), [(-179.9, 0.0), (-179.4, 0.0), (179.0, 0.0), (-1.2, 0.0), (0.4, 0.0),
                        (179.7, 2.6)],
         [(0, 0), (1, 0), (-1, 0), (179, 0), (-179, 0), (0, 3)]),
        # beam just right of -180°: leaves at or past az0 + pi lose 2 pi
        ((-179.7, 0.0), [(179.9, 0.0), (179.4, 0.0), (-179.0, 0.0), (0.5, 0.0), (0.1, 0.0)],
         [(0, 0), (-1, 0), (1, 0), (-180, 0), (180, 0)]),
        # beam near the zenith: elevations below the grid take its first node (-0.5°)
        ((0.0, 89.5), [(0.0, 89.9), (0.0, 88.3), (0.0, -30.0), (10.0, 60.2)],
         [(0, 0), (0, -1), (0, -90), (10, -29)]),
        # beam near the nadir: elevations above the grid take its last node (+0.5°)
        ((30.0, -89.5), [(30.0, 30.0), (31.6, -89.2)], [(0, 90), (2, 0)]),
    ],
    ids=["az+180", "az-180", "el+90", "el-90"],
)
def test_grid_node_choice_at_the_edges(centre: tuple[float, float],
                                       leaves: list[tuple[float, float]],
                                       expected: list[tuple[int, int]]) -> None:
    got = node_offsets(unit(*centre), leaves)
    np.testing.assert_allclose(got, np.array(expected, dtype=float), atol=1e-9)


def test_beam_exactly_at_180_degrees_keeps_the_seeds_wrap() -> None:
    """az0 = +pi wraps the far side; az0 = -pi (boresight y = -0.0) matches neither of the
    seed's two cases, so nothing is wrapped and a leaf 0.1° across the seam reads the far end
    node, 180° off: the seed's quirk, reproduced in grid mode, absent from the exact lookup."""
    plus = np.array([-1.0, 0.0, 0.0])
    minus = np.array([-1.0, -0.0, 0.0])
    leaves = [(179.9, 0.0), (-179.9, 0.0)]
    np.testing.assert_allclose(node_offsets(plus, leaves), [(0, 0), (0, 0)], atol=1e-9)
    np.testing.assert_allclose(node_offsets(minus, leaves), [(180, 0), (0, 0)], atol=1e-9)
    np.testing.assert_allclose(node_offsets(minus, leaves, "exact"), [(-0.1, 0), (0.1, 0)],
                               atol=1e-9)


def test_exact_lookup_keeps_each_leafs_own_angles() -> None:
    got = node_offsets(unit(0.0, 89.5), [(0.0, -30.0), (10.0, 60.2)], "exact")
    np.testing.assert_allclose(got, [(0.0, -119.5), (10.0, -29.3)], atol=1e-9)


def test_params_resolve_the_seed_defaults_and_reject_a_grid_without_seed2020() -> None:
    spec = EchoParams()
    assert spec.spreading is True and spec.beam_lookup == "exact" and not spec.seed2020
    paper = EchoParams(seed2020=True)
    assert paper.spreading is False and paper.beam_lookup == "grid"
    assert paper == EchoParams(seed2020=True, spreading=False, beam_lookup="grid")
    mixed = EchoParams(seed2020=True, spreading=True, beam_lookup="exact")
    assert mixed.spreading is True and mixed.beam_lookup == "exact"
    with pytest.raises(ValueError, match="beam_lookup='grid' needs seed2020"):
        EchoParams(beam_lookup="grid")
    with pytest.raises(ValueError, match="beam_lookup must be"):
        EchoParams(seed2020=True, beam_lookup="nearest")  # type: ignore[arg-type]


def test_a_leaf_reads_its_node_in_the_echo_and_an_ear_reads_the_grid_too() -> None:
    """A leaf 10.4° off in azimuth gets the gain of the 10° node; a colocated ear (the bistatic
    path) gives the same echo as the monostatic sonar."""
    beam = Beam.from_az_el([0, 0, 0], 0.0, 0.0, D(30.0))
    u = unit(10.4, 0.0)
    one = (u[None] * 2.0, -u[None], np.array([0.025]))
    grid = synthesize(one, beam, EchoParams(seed2020=True), fidelity="reference").samples
    exact = synthesize(one, beam, EchoParams(seed2020=True, beam_lookup="exact"),
                       fidelity="reference").samples
    sigma2 = beam.sigma**2
    ratio = math.exp(-(D(10.0) ** 2) / sigma2) / math.exp(-(D(10.4) ** 2) / sigma2)
    np.testing.assert_allclose(grid, exact * ratio, rtol=1e-9, atol=1e-12 * np.abs(grid).max())
    ear = synthesize(one, beam, EchoParams(seed2020=True, ears=(Ear(),)),
                     fidelity="reference").samples
    np.testing.assert_allclose(ear[0], grid, rtol=0, atol=1e-15 * np.abs(grid).max())
