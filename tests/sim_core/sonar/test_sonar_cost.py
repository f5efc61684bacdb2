"""The echo cost model (sim_core.sonar.cost): its closed form, its prediction's growth with the
leaves in range and the pre-cull cone, and that the realtime fidelity budgets with it."""

from __future__ import annotations

import dataclasses
import math

import pytest

from sim_core.sonar import EchoParams
from sim_core.sonar.cost import COST, EchoCost
from sim_core.sonar.fast import Realtime


def test_the_realtime_budget_plans_with_the_cost_model_the_server_schedules_with() -> None:
    budget = Realtime().leaf_budget(EchoParams(budget_s=5e-3))
    assert budget.budget_s == 5e-3
    for name in ("overhead_s", "per_examined_s", "per_candidate_s", "per_selected_s",
                 "per_leaf_s"):
        assert getattr(budget, name) == getattr(COST, name), name


def test_seconds_is_the_sum_of_its_terms() -> None:
    c = EchoCost(overhead_s=1.0, gather_s=2.0, per_examined_s=3.0, per_candidate_s=5.0,
                 per_selected_s=7.0, per_leaf_s=11.0)
    assert c.seconds(1, 1, 1, 1, gathered=1) == 1 + 2 + 3 + 5 + 7 + 11
    assert c.seconds(10, 4, 3, 2) == 1 + 30 + 20 + 21 + 22


def test_the_estimate_grows_with_leaves_in_range_and_the_cone() -> None:
    c = COST
    # no cone: only the overhead and the examined leaves
    assert c.estimate(10_000, 0.0) == pytest.approx(c.overhead_s + 10_000 * c.per_examined_s)
    # the whole sphere: every leaf a candidate, tested, half of them synthesised (kept 0.5)
    whole = c.overhead_s + 10_000 * (c.per_examined_s + c.per_candidate_s + c.per_selected_s
                                     + c.kept * c.per_leaf_s)
    assert c.estimate(10_000, math.pi) == pytest.approx(whole)
    # linear in the leaves beyond the overhead; the share of the sphere (1 - cos rho) / 2
    rho = math.radians(40)
    one, two = c.estimate(20_000, rho) - c.overhead_s, c.estimate(40_000, rho) - c.overhead_s
    assert two == pytest.approx(2 * one, rel=1e-3)
    narrow, wide = c.estimate(20_000, math.radians(20)), c.estimate(20_000, math.radians(40))
    assert narrow < wide
    assert c.estimate(20_000, rho, gathered=True) == pytest.approx(
        c.estimate(20_000, rho) + 20_000 * c.gather_s)


@pytest.mark.parametrize("field", ["overhead_s", "gather_s", "per_examined_s", "fill", "kept"])
def test_a_negative_or_non_finite_constant_is_refused_by_name(field: str) -> None:
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match=f"EchoCost.{field}"):
            dataclasses.replace(COST, **{field: bad})
    with pytest.raises(ValueError, match="per_leaf_s"):
        EchoCost(per_leaf_s=0.0)
