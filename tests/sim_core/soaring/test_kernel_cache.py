"""The soaring kernels' on-disk cache never hands back a kernel compiled with an old callee: the
kernels, split over several files, are cached as one unit (sim_core/soaring/kernels/cache.py).

The first two tests build a package of two cached kernels in a temporary directory, a caller
and its callee in another file, run the caller (compiled, written to the cache), edit the
callee, import the package again and run the caller: alone, numba loads the caller compiled with
the old callee (the limit the unit exists for, shown on this numba); bound as a unit, the edit
is seen."""

from __future__ import annotations

import importlib
import sys
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from sim_core.soaring import kernels
from sim_core.soaring.kernels.cache import unit_stamp

CALLEE = "from numba import njit\n\n\n@njit(cache=True)\ndef f(x):\n    return x + {add}\n"
CALLER = ("from numba import njit\n\nfrom {pkg}.callee import f\n\n\n"
          "@njit(cache=True)\ndef g(x):\n    return 2.0 * f(x)\n")
BOUND = ("from sim_core.soaring.kernels.cache import bind\n\n"
         "from {pkg} import callee, caller\n\nbind((callee, caller))\n")


@pytest.fixture
def package(tmp_path: Path) -> Iterator[Callable[[bool], tuple[str, Path]]]:
    names: list[str] = []

    def make(bound: bool) -> tuple[str, Path]:
        pkg = f"unit_{uuid.uuid4().hex[:8]}"
        root = tmp_path / pkg
        root.mkdir()
        (root / "__init__.py").write_text(BOUND.format(pkg=pkg) if bound else "")
        (root / "callee.py").write_text(CALLEE.format(add="1.0"))
        (root / "caller.py").write_text(CALLER.format(pkg=pkg))
        names.append(pkg)
        return pkg, root

    sys.path.insert(0, str(tmp_path))
    yield make
    sys.path.remove(str(tmp_path))
    for pkg in names:
        for mod in [m for m in sys.modules if m == pkg or m.startswith(f"{pkg}.")]:
            del sys.modules[mod]


def _run_edit_run(pkg: str, root: Path) -> tuple[float, float]:
    """g(1.0) with f(x) = x + 1, then, after f became x + 100 in its file, g(1.0) again from a
    fresh import (the cache of the first run on disk)."""
    first = importlib.import_module(f"{pkg}.caller").g(1.0)
    (root / "callee.py").write_text(CALLEE.format(add="100.0"))
    for mod in [m for m in sys.modules if m == pkg or m.startswith(f"{pkg}.")]:
        del sys.modules[mod]
    importlib.invalidate_caches()
    importlib.import_module(pkg)
    return first, importlib.import_module(f"{pkg}.caller").g(1.0)


def test_numba_alone_keeps_a_caller_compiled_with_an_old_callee(
    package: Callable[[bool], tuple[str, Path]]
) -> None:
    assert _run_edit_run(*package(False)) == (4.0, 4.0)  # stale: 2 (1 + 1), not 2 (1 + 100)


def test_a_unit_compiles_its_callers_again_when_a_callee_changes(
    package: Callable[[bool], tuple[str, Path]]
) -> None:
    assert _run_edit_run(*package(True)) == (4.0, 202.0)


def test_every_kernel_file_is_in_the_unit_and_every_kernel_bound() -> None:
    files = {p.stem for p in Path(kernels.__file__).parent.glob("*.py")}
    assert {m.__name__.rsplit(".", 1)[1] for m in kernels.UNIT} == files - {"__init__", "cache"}
    stamp = unit_stamp(kernels.UNIT)
    bound = [f for m in kernels.UNIT for f in vars(m).values()
             if getattr(getattr(f, "py_func", None), "__module__", None) == m.__name__]
    assert len(bound) == kernels.cache.bind(kernels.UNIT) > 0
    assert {f._cache._cache_file._source_stamp for f in bound} == {stamp}
