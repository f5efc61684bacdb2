"""Echo determinism: the same seed gives the same echo, bit for bit; another seed another echo.

The echo model itself draws no random numbers; its randomness is the scene's (the seeded tree
and forest). Same machine only: bits across SIMD paths are not compared (docs/testing.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from sim_core.sonar import EchoParams, synthesize
from sim_core.sonar.scenarios import fig6_scene


@pytest.mark.parametrize("fidelity", ["reference", "fast"])
def test_echo_same_seed_identical_other_seed_different(fidelity: str) -> None:
    echoes = []
    for seed in (1, 1, 2):
        leaves, pings = fig6_scene(seed=seed)
        echoes.append(synthesize(leaves, pings[1].beam, EchoParams(), fidelity=fidelity))
    same, again, other = echoes
    assert same.leaves_in_beam > 0
    np.testing.assert_array_equal(same.samples, again.samples)
    assert same.leaves_in_beam == again.leaves_in_beam
    assert same.samples.shape == other.samples.shape
    assert not np.array_equal(same.samples, other.samples)
