"""numba's on-disk cache for the kernels, kept fresh across the modules of this package.

:func:`kernel` is ``numba.njit(cache=True, error_model="numpy")``: machine code is written to
``__pycache__`` beside the module (or under ``NUMBA_CACHE_DIR``) and reused by later processes,
so the compile cost is paid once per installation and CPU (``sim_core.soaring.warm_up``).

numba stamps a cached function with its own source file only, yet a kernel carries the code of
every kernel it calls and the values of the constants it reads, most of them from other modules
of this package: a change there would leave it stale. So every kernel's cache is stamped with the
contents of all the package's modules as well (:func:`package_stamp`): a change to any of them
recompiles them all, as a change to the one ``kernels.py`` they came from did.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

from numba import njit
from numba.core.caching import CompileResultCacheImpl, FunctionCache
from numba.core.dispatcher import Dispatcher

__all__ = ["PACKAGE", "kernel", "package_stamp"]

#: the directory whose modules share one cache stamp
PACKAGE = Path(__file__).resolve().parent

F = TypeVar("F", bound=Callable[..., Any])


def package_stamp(package: Path) -> str:
    """SHA-256 of the names and contents of the ``*.py`` files of ``package``, in name order."""
    digest = hashlib.sha256()
    for path in sorted(package.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


@functools.cache
def _stamp() -> str:
    """This package's stamp, once per process (as numba stamps a file when a kernel is made)."""
    return package_stamp(PACKAGE)


class _PackageStamped:
    """Mixin for a numba cache locator: its source stamp also covers the whole package."""

    def get_source_stamp(self) -> Any:
        return (super().get_source_stamp(), _stamp())  # type: ignore[misc]


#: numba's cache locators, in numba's order, each with the package-wide stamp
_LOCATORS: list[type[object]] = [
    type(f"PackageStamped{cls.__name__}", (_PackageStamped, cls), {})
    for cls in CompileResultCacheImpl._locator_classes
]


class _Impl(CompileResultCacheImpl):
    _locator_classes = _LOCATORS


class _Cache(FunctionCache):
    _impl_class = _Impl


def kernel(fn: F) -> F:
    """Compile ``fn`` with numba (nopython, numpy's error model), cached on disk under the
    package-wide stamp."""
    disp = njit(error_model="numpy")(fn)
    if isinstance(disp, Dispatcher):  # not under NUMBA_DISABLE_JIT, which returns fn itself
        # what cache=True does (Dispatcher.enable_caching), with this package's cache class
        disp._cache = _Cache(fn)  # type: ignore[attr-defined]
    return cast(F, disp)
