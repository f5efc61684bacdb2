"""Parity with the seeds' own code: echoloop against the outputs of the seeds' code, run.

Writes ``docs/parity.md`` (one table per seed: what was compared, on which data, the measured
difference, and each deliberate deviation with its reason) and returns the measured tables for
BENCHMARKS.md. What is compared is what the golden tests compare: this module takes their
definitions (scenes, variants, cases, helpers) from the test modules, so the report and the
tests cannot drift apart.
"""

from __future__ import annotations

import csv
import math
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import table
from hil_bridge.files.soaring import load_law
from sim_core.soaring import Law
from sim_core.soaring import run as run_swarm
from sim_core.sonar import EchoParams, synthesize
from tests.sim_core.soaring import test_soaring_seed002_golden as g002
from tests.sim_core.sonar import test_sonar_seed000_golden as g000
from tests.sim_core.world import test_world_seed001_cpp as g001

TITLE = "Parity with the seeds' own code"

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
DOC = ROOT / "docs" / "parity.md"
#: pings timed per scene and fidelity (CPU-time medians)
PINGS = 5
#: echoloop trees grown per species for the seed 001 comparison
TREES = 40
#: the packaged law's three values as they were before issue 13 (rounded to 6 digits)
ROUNDED = {"fov": 5.759587, "bankMin": -0.261799, "bankMax": 0.261799}


def _ping_cpu(leaves: Any, beam: Any, params: EchoParams, fidelity: str) -> float:
    """Median CPU seconds of PINGS echoes after one warm-up."""
    synthesize(leaves, beam, params, fidelity=fidelity)
    times = []
    for _ in range(PINGS):
        c0 = time.process_time()
        synthesize(leaves, beam, params, fidelity=fidelity)
        times.append(time.process_time() - c0)
    return float(np.median(times))


def _sci(x: float) -> str:
    return f"{x:.1e}" if x else "0"


def _seed000() -> tuple[list[str], list[str]]:
    """(docs/parity.md lines, BENCHMARKS.md lines) for the echo."""
    rows, timing = [], []
    octave = {r["scene"]: r for r in csv.DictReader(
        (DATA / "seed000_matlab" / "octave_seconds.csv").open(encoding="utf-8"))}
    for scene_name in g000.SCENES:
        scene, leaves_path = g000.load_scene(DATA, scene_name)
        leaves, beam = g000.leaves_of(leaves_path), g000.beam_of(scene)
        for variant, kw in g000.VARIANTS.items():
            params = EchoParams(**kw)
            ref = synthesize(leaves, beam, params, fidelity="reference")
            fast = synthesize(leaves, beam, params, fidelity="fast")
            want = scene[f"{variant}_echo"]
            rows.append([scene_name, f"`{variant}`", f"`{' '.join(g000.FLAGS[variant])}`",
                         f"{int(scene[f'{variant}_kept'])} / {ref.leaves_in_beam}",
                         _sci(g000.rel_l2(ref.samples, want)),
                         _sci(g000.rel_l2(fast.samples, want))])
        paper = EchoParams(seed2020=True)
        t_ref = _ping_cpu(leaves, beam, paper, "reference")
        t_fast = _ping_cpu(leaves, beam, paper, "fast")
        o = octave[scene_name]
        timing.append([scene_name, o["kept"], f"{float(o['cpu_s']) * 1e3:.0f} ms",
                       f"{t_ref * 1e3:.1f} ms", f"{float(o['cpu_s']) / t_ref:.1f}x",
                       f"{t_fast * 1e3:.2f} ms", f"{float(o['cpu_s']) / t_fast:.0f}x"])
    gap = [f"{scene_name} {g000.rel_l2(s['demo_echo'], s['demo_exact_echo']) * 100:.1f} %"
           for scene_name in g000.SCENES
           for s in [g000.load_scene(DATA, scene_name)[0]]]
    parity = table(["scene", "seed variant", "echoloop flags", "kept (seed / ours)",
                    "rel. L2 `reference`", "rel. L2 `fast`"], rows)
    times = table(["scene", "kept", "seed, Octave (CPU/ping)", "`--seed2020 reference`",
                   "speed-up", "`--seed2020 fast`", "speed-up"], timing)
    doc = [
        "## Seed 000: foliage echo (Tanveer et al. 2020)",
        "",
        "Data: `tests/data/seed000_matlab` (the seed's MATLAB echo pipeline run under GNU Octave "
        "7.3 on two leaf sets, three beams; README there). Compared: leaves kept (exactly) and "
        "the 24000-sample impulse response (relative L2), for each of the seed's four variants "
        "with the `echoloop echo` flags that select it (`EchoParams(seed2020=True, "
        "beam_lookup=..., spreading=...)`). Golden test: "
        "`tests/sim_core/sonar/test_sonar_seed000_golden.py` (bound 1e-10 for `reference`).",
        "",
        parity,
        "",
        f"The 1° grid alone moves the seed's own waveform by {', '.join(gap)} (its `demo` vs "
        "`demo_exact`): the grid mode reproduces it node for node "
        "(`sim_core/sonar/seedbeam.py`, edges in `test_sonar_seedbeam.py`). The remaining "
        "~1e-12 is one ulp of the seed's range (computed through a spherical round trip) in a "
        "two-way phase of up to 1.5e4 rad. `fast` differs by its own interpolation error.",
        "",
        "Time per ping, CPU (the seed's from `octave_seconds.csv`, measured once on this machine "
        "class; ours in this run):",
        "",
        times,
        "",
        "Deliberate deviations of the default model (`EchoParams()`, docs/spec/echo_model.md) "
        "from the seed's paper code, each undone by `seed2020`:",
        "",
        table(["default", "seed paper code", "why"], [
            ["off-axis angle from the boresight, arccos(u·b)", "raw (Δaz, Δel), wrapped",
             "raw az/el differences blow up a beam's footprint near ±90° elevation"],
            ["Gaussian evaluated at each leaf", "nearest node of a 1° grid",
             "the grid moves the waveform by 2.6-24 %; it is a lookup artefact"],
            ["1/r² spreading", "none (`./r.*r` cancels; the stand-alone copy has it)",
             "the paper's own formula has it"],
            ["cone pre-cull, a ≥ 1 mm, r ≥ 0.1 m, window check", "none",
             "guards (spec); no leaf of these scenes is affected"],
        ]),
        "",
        "Not reproduced: the stand-alone copy's own pipeline (`Sim_leaf_scattering.m`): its "
        "lookup reads an uncentred absolute grid and its Fs = 100 kHz is below Nyquist.",
    ]
    bench = ["### Seed 000 echo: relative L2 per scene and variant", "", parity, "",
             "### Seed 000 echo: time per ping vs the seed's Octave time", "", times]
    return doc, bench


def _seed001() -> list[str]:
    seed = g001.seed_trees(DATA)
    rows = []
    for species, name in g001.SPECIES.items():
        mine = seed[seed["species"] == species]
        ours = g001.echoloop_trees(species, TREES)
        for stat in g001.STATS:
            a, b = mine[stat], ours[stat]
            rows.append([name, stat, f"{a.mean():.4g} ± {a.std(ddof=1) / math.sqrt(a.size):.2g}",
                         f"{b.mean():.4g} ± {b.std(ddof=1) / math.sqrt(b.size):.2g}",
                         f"{g001.z_score(b, a):+.1f}"])
    return [
        "## Seed 001: L++ trees (Wahed et al. 2022)",
        "",
        "Data: `tests/data/seed001` (the seed's four grammars, byte-identical to the packaged "
        "ones, its IPP points and 31-tree forest map, both tested) and `tests/data/seed001_cpp` "
        "(per-tree statistics of the seed's C++ forest, `meshpro forest`, README there). The "
        "seed draws from glibc `rand()`, so trees compare as distributions: the seed's 10/6/8/7 "
        f"trees per species against {TREES} echoloop trees each (grammar units, "
        "`leaf_size: seed`), mean ± standard error and z of the difference. Exact: the trunk "
        "radius (header thickness), the reduction 0.95 and the leaf-length range 0.7-1.3 × "
        "leafSize (`test_world_seed001_cpp.py`); the radius commands `<` `>` `=` `%` against a "
        "step-by-step turtle on the four grammars and a hand-worked grammar "
        "(`test_world_lpp.py`).",
        "",
        table(["species", "per tree", "seed C++", "echoloop", "z"], rows),
        "",
        "Deliberate deviations:",
        "",
        table(["echoloop", "seed", "why"], [
            ["turtle frame reset for every tree", "`right` leaks from tree to tree",
             "a tree's shape must not depend on the trees grown before it"],
            ["`\\|` turns 180°", "turns 3.14° (π passed as degrees)", "a units bug; unused"],
            ["leaf size `metres` by default: radius N(μ, 20 %) in metres",
             "`leaf_size: seed`: N(leafSize, 15 %) clipped, grammar units",
             "the seed's leaves are 0.5-0.8 m long at 12-20 m tall trees, outside the leaf "
             "echo model's fit"],
            ["the grammar unit is `unit_m` metres", "no unit", "echoes need metres"],
            ["thickness narrowed below 0 gives radius 0", "a mirrored cylinder",
             "no negative radii"],
        ]),
    ]


def _seed002() -> tuple[list[str], list[str]]:
    rows = []
    for case in g002.CASES:
        path, seed = g002.case_files(DATA, case)
        steps = seed["aliveData"].shape[1]
        got, strength, on_time = g002.fly(path, steps)
        diffs = {name: float(np.abs(got[name] - seed[key][:, :steps]).max())
                 for name, key in g002.STATE.items()}
        result = run_swarm(load_law(path))
        m = result.metrics
        same = on_time and bool(np.array_equal(got["alive"], seed["aliveData"]))
        if "thermalStrength" in seed:
            same &= bool(np.array_equal(strength, seed["thermalStrength"]))
        height_rel = abs(m.heightScore - float(seed["heightScore"])) / float(seed["heightScore"])
        rows.append([
            case, str(steps), f"{max(diffs['x'], diffs['y'], diffs['z']):.1e} m",
            f"{diffs['heading']:.1e}", f"{diffs['bank']:.1e}", f"{diffs['speed']:.1e}",
            f"{diffs['omega']:.1e}", f"{diffs['vz']:.1e}",
            "identical" if same else "DIFFER",
            f"{int(m.surviving)}/{int(m.groundDeaths)}/{int(m.collisionDeaths)} vs "
            f"{int(seed['surviving'])}/{int(seed['groundDeaths'])}/"
            f"{int(seed['collisionDeaths'])}",
            _sci(height_rel),
        ])
    traces = table(["case", "steps", "max Δ position", "Δ heading rad", "Δ bank rad",
                    "Δ airspeed m/s", "Δ turn rate rad/s", "Δ vz m/s", "alive, thermals",
                    "survive/ground/collide (ours vs seed)", "heightScore rel."], rows)
    exact = run_swarm(Law())
    rounded = run_swarm(Law().replace(**ROUNDED))
    law_rows = [[label, f"{r.metrics.surviving}/40", f"{r.metrics.heightScore:.4g}",
                 f"{r.metrics.thermalUseScore:.6g}"]
                for label, r in (("exact (packaged)", exact), ("rounded (before)", rounded))]
    law_table = table(["default law, seed 2", "survivors", "heightScore m·s",
                       "thermalUseScore agent·s"], law_rows)
    doc = [
        "## Seed 002: thermal-soaring swarm (Pooley et al. 2023)",
        "",
        "Data: `tests/data/seed002_matlab` (the seed's MATLAB simulation run under GNU Octave "
        "7.3 with pinned gliders and thermals; README there). Compared after every step: "
        "position, heading, bank, airspeed, turn rate, vertical speed, who is alive, thermal "
        "strengths; and the final metrics. Golden test: "
        "`tests/sim_core/soaring/test_soaring_seed002_golden.py` (through `echoloop swarm run "
        "--trace` and `SwarmSim.step`; glide and thermal crossing exact, `swarm5` within 1e-6 "
        "m, about ten times what the numpy step it replaced left).",
        "",
        traces,
        "",
        "The soaring kernels evaluate the seed's expressions as GNU Octave does (`norm` as "
        "Octave's scaled sum of squares, a scalar `x^2` as libm `pow`, `./` as a division, "
        "`dot` as one fused multiply-add; docs/soaring.md, 'How the step is computed'), so "
        "with this machine's libm the cases can match to the last bit. Before, the numpy "
        "step left `swarm5` 1.0e-7 m (AVX-512) / 1.2e-7 m (AVX2) away, the controller "
        "amplifying last-bit differences while its bank chatters at the limits. The thermal "
        "strengths and every integer metric are identical in all three cases.",
        "",
        "The law: the packaged `law_40survivors.yaml` holds the spreadsheet's values as stored "
        "(fov 5.7595865315812871, bank limits ±0.26179938779914941); tested against every "
        "case file. Rounding those three to 6 digits, as the law did before, changes a chaotic "
        "40-glider run (this run's CPU path):",
        "",
        law_table,
        "",
        "Deliberate deviations:",
        "",
        table(["echoloop", "seed", "why"], [
            ["`survivingPercent` 0-100", "a fraction 0-1 (`MainScriptFunction`)",
             "its analysis scripts multiply by 100; the JSON says percent"],
            ["random draws from numpy's PCG64 (`derive_rng`)", "MATLAB `rng(seed,'threefry')`",
             "one generator per subsystem; random runs compare as statistics, pinned cases "
             "step by step"],
            ["`controller`, `migrationTarget`, `thermalFadeMode`, rate limits", "—",
             "extensions, off (the seed's behaviour) by default"],
        ]),
    ]
    bench = ["### Seed 002 soaring: max trace difference per case", "", traces, "",
             law_table]
    return doc, bench


def _wrap(block: str) -> str:
    """Prose at 100 columns; headings and tables as they are."""
    if not block or block.startswith(("#", "|")):
        return block
    return textwrap.fill(block, 100, break_long_words=False, break_on_hyphens=False)


def run_parity() -> tuple[str, str]:
    """(docs/parity.md, BENCHMARKS.md section)."""
    doc0, bench0 = _seed000()
    doc1 = _seed001()
    doc2, bench2 = _seed002()
    header = [
        "# Parity with the seeds' own code",
        "",
        "Written by `python -m bench parity` (do not edit by hand): echoloop against the "
        "outputs of each seed's own code, run on the same inputs. Differences are measured in "
        "the run that wrote this file; the golden tests named below hold them to bounds that "
        "also pass with numpy's AVX-512 kernels off.",
        "",
    ]
    doc = "\n".join(_wrap(x) for x in [*header, *doc0, "", *doc1, "", *doc2]) + "\n"
    return doc, "\n".join([*bench0, "", *bench2])


def run(out_dir: Path) -> str:
    doc, section = run_parity()
    DOC.write_text(doc, encoding="utf-8")
    return section + "\n\nFull report: [docs/parity.md](docs/parity.md).\n"


__all__ = ["TITLE", "run"]
