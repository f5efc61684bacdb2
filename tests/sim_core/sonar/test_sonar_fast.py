"""Fast fidelities against the reference: documented bounds, realtime budget, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_core.sonar import FIDELITIES, Beam, EchoParams, Fast, Realtime, synthesize
from sim_core.sonar.model import prepare
from tests.sim_core.sonar._scenes import cone_cloud, rel_l2

BEAM = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(30.0))


def test_table_has_the_three_fidelities_with_one_signature() -> None:
    assert {"reference", "fast", "realtime"} <= set(FIDELITIES)
    for name, impl in FIDELITIES.items():
        assert impl.name == name and callable(impl.run)
    with pytest.raises(ValueError, match="unknown fidelity 'exact'"):
        synthesize(cone_cloud(5), BEAM, fidelity="exact")


@pytest.mark.parametrize("bw_deg", [10.0, 30.0, 60.0])
def test_fast_error_within_1e3_and_within_its_reported_bound(bw_deg: float) -> None:
    beam = Beam([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], math.radians(bw_deg))
    leaves = cone_cloud(1500, seed=int(bw_deg), half_angle_deg=bw_deg / 2)
    ref = synthesize(leaves, beam, fidelity="reference")
    fast = synthesize(leaves, beam, fidelity="fast")
    err = rel_l2(fast.samples, ref.samples)
    assert fast.leaves_in_beam == ref.leaves_in_beam > 500
    assert fast.error_bound is not None
    assert err <= 1e-3
    assert err <= fast.error_bound


@pytest.mark.parametrize(("order", "eps"), [(2, 1e-6), (3, 1e-3), (4, 1e-6), (6, 1e-9)])
def test_fast_options_stay_within_their_bound(order: int, eps: float) -> None:
    leaves = cone_cloud(800, seed=order)
    ref = synthesize(leaves, BEAM, fidelity="reference")
    fast = synthesize(leaves, BEAM, fidelity=Fast(order=order, eps=eps, adapt=None))
    assert fast.error_bound is not None
    assert rel_l2(fast.samples, ref.samples) <= fast.error_bound


def test_realtime_under_budget_equals_fast_quality_and_over_budget_bounds_its_error() -> None:
    leaves = cone_cloud(3000, seed=11)
    ref = synthesize(leaves, BEAM, fidelity="reference")
    roomy = synthesize(leaves, BEAM, EchoParams(budget_s=1.0), fidelity="realtime")
    assert roomy.leaves_in_beam == ref.leaves_in_beam
    assert rel_l2(roomy.samples, ref.samples) <= roomy.error_bound  # type: ignore[operator]
    tight = Realtime(overhead_s=0.0, per_leaf_s=1e-6, per_examined_s=0.0, per_selected_s=0.0,
                     per_candidate_s=0.0)
    params = EchoParams(budget_s=1e-3)  # room for 1000 leaves
    echo = synthesize(leaves, BEAM, params, fidelity=tight)
    assert tight.capacity(params) == 1000
    assert echo.leaves_in_beam == ref.leaves_in_beam
    assert echo.error_bound is not None and echo.error_bound > 0.0
    err = rel_l2(echo.samples, ref.samples)
    assert 0.0 < err <= echo.error_bound
    # fewer leaves -> larger bound
    tighter = synthesize(leaves, BEAM, EchoParams(budget_s=2e-4), fidelity=tight)
    assert tighter.error_bound > echo.error_bound  # type: ignore[operator]


def test_realtime_budget_pays_for_the_geometry_of_every_examined_leaf() -> None:
    leaves = cone_cloud(4000, seed=12)
    costly = Realtime(overhead_s=1e-3, per_leaf_s=1e-6, per_examined_s=1e-6, per_selected_s=1e-6,
                      per_candidate_s=1e-7)
    budget = costly.leaf_budget(EchoParams(budget_s=6e-3))
    # 4000 examined leaves cost 4 ms; the 4000 candidates 0.4 ms: 0.6 ms are left to test and
    # synthesise the 300 nearest
    assert budget.candidates(4000) == 476
    assert budget.tested(4000, 4000) == 300
    assert budget.synthesised(4000, 4000, 300) == 300
    scene = prepare(leaves, BEAM, EchoParams(budget_s=6e-3), budget=budget)
    assert scene.count <= 300 and scene.in_beam == scene.count + scene.cut.count
    assert scene.cut.count > 0 and scene.cut.amax[0] > 0.0
    # nothing affordable: a zero echo whose relative error is exactly the reported 1
    broke = synthesize(leaves, BEAM, EchoParams(budget_s=1e-3), fidelity=costly)
    assert not broke.samples.any() and broke.error_bound == 1.0


@pytest.mark.parametrize("seed", range(6))
def test_realtime_bound_holds_on_random_scenes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    bw = float(rng.uniform(10.0, 70.0))
    beam = Beam([0.0, 0.0, 0.0], [1.0, float(rng.uniform(-0.2, 0.2)), 0.0], math.radians(bw))
    leaves = cone_cloud(int(rng.integers(1500, 4000)), seed=100 + seed,
                        half_angle_deg=bw * float(rng.uniform(0.4, 1.0)),
                        r_lo=float(rng.uniform(0.2, 2.0)), r_hi=float(rng.uniform(4.0, 9.5)))
    ref = synthesize(leaves, beam, fidelity="reference")
    per_examined = float(rng.choice([0.0, 2e-7]))
    fid = Realtime(overhead_s=0.0, per_leaf_s=1e-6, per_examined_s=per_examined,
                   per_selected_s=float(rng.choice([0.0, 3e-7])),
                   per_candidate_s=float(rng.choice([0.0, 2e-7])))
    for budget_s in (3e-4, 1e-3, 2e-3):
        echo = synthesize(leaves, beam, EchoParams(budget_s=budget_s), fidelity=fid)
        assert echo.error_bound is not None
        assert rel_l2(echo.samples, ref.samples) <= echo.error_bound


def test_fast_is_deterministic() -> None:
    leaves = cone_cloud(2000, seed=2)
    a = synthesize(leaves, BEAM).samples
    b = synthesize(leaves, BEAM).samples
    np.testing.assert_array_equal(a, b)


def test_fast_handles_a_million_leaves_once() -> None:
    c, n, a = cone_cloud(1_000_000, seed=9, half_angle_deg=60.0, r_lo=0.05, r_hi=30.0)
    c[:10] = np.nan
    echo = synthesize((c, n, a), BEAM, fidelity="fast")
    assert echo.dropped >= 10
    assert 0 < echo.leaves_in_beam < 1_000_000
    assert np.all(np.isfinite(echo.samples)) and echo.samples.any()
    assert echo.error_bound is not None and echo.error_bound < 1e-3


def test_fast_rejects_doppler_with_a_clear_message() -> None:
    params = EchoParams(platform_velocity=(10.0, 0.0, 0.0), doppler=True)
    with pytest.raises(ValueError, match=r"Doppler.*reference"):
        synthesize(cone_cloud(10), BEAM, params, fidelity="fast")


def test_fast_validates_its_options() -> None:
    with pytest.raises(ValueError, match="order"):
        Fast(order=0)
    with pytest.raises(ValueError, match="eps"):
        Fast(eps=0.5)


def test_large_world_leaves_are_culled_through_their_index_with_the_same_echo() -> None:
    from sim_core.sonar.model import INDEX_MIN_LEAVES
    from sim_core.world import Leaves

    c, n, a = cone_cloud(INDEX_MIN_LEAVES, seed=4, half_angle_deg=90.0, r_lo=0.0, r_hi=40.0)
    world = Leaves(c, n, a, np.zeros(len(a), dtype=np.int32))
    via_index = synthesize(world, BEAM)
    plain = synthesize((c, n, a), BEAM)
    assert via_index.leaves_in_beam == plain.leaves_in_beam > 0
    np.testing.assert_array_equal(via_index.samples, plain.samples)
