"""The test suite's cost: what CI (``.ci/run``) spends on ``make test`` and its second pass.

Runs the two passes of ``.ci/run`` one after the other, as ``make test`` and
``make test-noavx512`` run them (``python -m pytest -q``, then the same with numpy's AVX-512
kernels disabled through ``NPY_DISABLE_CPU_FEATURES``, without the cache provider and without
the tests that hold no float result: the Makefile's marker expression, ``processes`` and
``no_simd_float``), and
reports each pass's wall time, its CPU time (user + system of pytest and its children) and
the total against the 10-minute budget of the project's guide. The machine is shared: the wall
time includes whatever else ran, the CPU time does not.
"""

from __future__ import annotations

import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

from bench._util import table

TITLE = "Test suite: make test and the AVX-512-off pass"

ROOT = Path(__file__).resolve().parent.parent
BUDGET_S = 600.0


def _noavx512() -> str:
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    m = re.search(r"^NOAVX512 := (.+)$", makefile, re.M)
    if m is None:
        raise ValueError("Makefile: no NOAVX512 := ... line (the second CI pass's features)")
    return m.group(1).strip()


def _noavx512_markers() -> str:
    """The second pass's ``-m`` expression, as the Makefile's ``test-noavx512`` gives it."""
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    m = re.search(r'^test-noavx512:.*\n\t.*-m "([^"]+)"', makefile, re.M)
    if m is None:
        raise ValueError('Makefile: no -m "..." in test-noavx512 (the second CI pass\'s tests)')
    return m.group(1)


def _pass(extra_env: dict[str, str], extra_args: list[str]) -> tuple[float, float, str]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", *extra_args], cwd=ROOT,
                          env={**os.environ, **extra_env}, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    last = (proc.stdout.strip().splitlines() or ["(no output)"])[-1]
    return wall, cpu, last.strip("= ")


def run(out_dir: Path) -> str:
    first = _pass({}, [])
    second = _pass({"NPY_DISABLE_CPU_FEATURES": _noavx512()},
                   ["-p", "no:cacheprovider", "-m", _noavx512_markers()])
    total = first[0] + second[0]
    rows = [
        ["`make test`", f"{first[0] / 60:.1f} min", f"{first[1] / 60:.1f} min", first[2]],
        ["`make test-noavx512`", f"{second[0] / 60:.1f} min", f"{second[1] / 60:.1f} min",
         second[2]],
        ["both (`.ci/run`)", f"{total / 60:.1f} min", f"{(first[1] + second[1]) / 60:.1f} min",
         f"{100 * total / BUDGET_S:.0f} % of the {BUDGET_S / 60:.0f}-minute budget"],
    ]
    return table(["pass", "wall", "CPU (user + sys)", "result"], rows)
