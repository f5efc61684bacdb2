"""The kernels' on-disk cache: one stamp for the whole package, loaded by later processes.

A kernel carries the code of the kernels it calls and the constants it reads from the other
modules of ``sim_core.soaring.kernels``; numba alone stamps it with its own file, so the
package stamps every kernel with all of its modules (``kernels.cache``).
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

from numba.core.dispatcher import Dispatcher

from sim_core.soaring.kernels.cache import PACKAGE, package_stamp

ROOT = Path(__file__).resolve().parents[3]
MODULES = ("octave", "glider", "thermals", "boids", "step")

#: a fresh process: warm up, then count the kernels numba loaded from disk and compiled
PROBE = f"""
import importlib, json
from numba.core.dispatcher import Dispatcher
import sim_core.soaring as s
s.warm_up()
hits = misses = 0
for name in {MODULES!r}:
    mod = importlib.import_module("sim_core.soaring.kernels." + name)
    for obj in vars(mod).values():
        if isinstance(obj, Dispatcher) and obj.__module__ == mod.__name__:
            hits += sum(obj.stats.cache_hits.values())
            misses += sum(obj.stats.cache_misses.values())
print(json.dumps({{"hits": hits, "misses": misses}}))
"""


def _kernels() -> list[Dispatcher]:
    out = []
    for name in MODULES:
        mod = importlib.import_module(f"sim_core.soaring.kernels.{name}")
        out += [obj for obj in vars(mod).values()
                if isinstance(obj, Dispatcher) and obj.__module__ == mod.__name__]
    return out


def test_package_stamp_changes_with_any_module(tmp_path: Path) -> None:
    for name in ("a.py", "b.py"):
        (tmp_path / name).write_text(f"X = {name!r}\n")
    (tmp_path / "notes.txt").write_text("not a module\n")
    first = package_stamp(tmp_path)
    assert package_stamp(tmp_path) == first
    (tmp_path / "notes.txt").write_text("changed, still not a module\n")
    assert package_stamp(tmp_path) == first
    (tmp_path / "b.py").write_text("X = 'b'  # edited\n")
    edited = package_stamp(tmp_path)
    assert edited != first
    (tmp_path / "c.py").write_text("")
    assert package_stamp(tmp_path) not in (first, edited)


def test_every_kernel_is_stamped_with_the_whole_package() -> None:
    kernels = _kernels()
    assert len(kernels) >= 20
    stamp = package_stamp(PACKAGE)
    for disp in kernels:
        own, package = disp._cache._impl.locator.get_source_stamp()
        assert package == stamp, disp
        assert own  # numba's stamp of the kernel's own file is kept beside it


def test_a_later_process_loads_every_kernel_from_the_cache() -> None:
    # this session compiled or loaded every kernel at its start (tests/conftest.py)
    proc = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, check=True)
    counts = json.loads(proc.stdout.strip().splitlines()[-1])
    assert counts["misses"] == 0, counts
    assert counts["hits"] > 0, counts
