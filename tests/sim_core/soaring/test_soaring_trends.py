"""Seed 002 §3.4 trends on a reduced grid: survival grows with numAgents, numThermals and
migration. Gliders spawn low (400–700 m) so the 1200 s runs separate the cases; six seeds each."""

from __future__ import annotations

import numpy as np

from sim_core.soaring import Law, run_batch

BASE = Law().replace(totalTime=1200.0, agentSpawnAltiRange=[400.0, 700.0])
SEEDS = range(1, 7)
CASES: dict[tuple[str, str], dict[str, float]] = {
    ("numAgents", "low"): {"numAgents": 10},
    ("numAgents", "high"): {"numAgents": 40},
    ("numThermals", "low"): {"numThermals": 1},
    ("numThermals", "high"): {"numThermals": 12},
    ("migration", "low"): {"migration": 1e-23},
    ("migration", "high"): {"migration": 1e-21},
}


def test_survival_grows_with_agents_thermals_and_migration() -> None:
    laws, tags = [], []
    for tag, kw in CASES.items():
        for s in SEEDS:
            laws.append(BASE.replace(rngSeed=s, **kw))
            tags.append(tag)
    results = run_batch(laws)
    mean: dict[tuple[str, str], float] = {}
    for tag in CASES:
        vals = [r.metrics.survivingPercent for r, t in zip(results, tags, strict=True) if t == tag]
        mean[tag] = float(np.mean(vals))
    for param in ("numAgents", "numThermals", "migration"):
        low, high = mean[(param, "low")], mean[(param, "high")]
        assert high > low + 10.0, (param, low, high)
