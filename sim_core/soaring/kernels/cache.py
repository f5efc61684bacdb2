"""Kernels in several files cached as one unit: a change to any file compiles all of them again.

numba's on-disk cache checks a cached function against its own source file only (numba's "Notes
on Caching", *Cache invalidation*: changes in symbols defined in another file are not seen). A
kernel compiled with a callee of another file carries the callee's code inside it, and a
constant of another file compiled in as a value, so after an edit of that file the cache would
hand back the caller with the old callee or value. :func:`bind` checks every cached kernel of a
unit of modules against one stamp of all their sources instead (:func:`unit_stamp`), so an edit
of any of them invalidates every kernel of the unit. Where a numba release has no cache of this
shape the unit's kernels compile without one (slower to start, never stale), with a warning.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Sequence
from types import ModuleType
from typing import Any

from numba.core.caching import NullCache
from numba.core.dispatcher import Dispatcher

__all__ = ["bind", "unit_stamp"]


def unit_stamp(modules: Sequence[ModuleType]) -> str:
    """sha256 of the names and sources of ``modules`` (read through their loaders), in name
    order."""
    digest = hashlib.sha256()
    for module in sorted(modules, key=lambda m: m.__name__):
        loader = module.__spec__.loader if module.__spec__ is not None else None
        source = getattr(loader, "get_source", lambda name: None)(module.__name__)
        digest.update(f"{module.__name__}\0{source or ''}\0".encode())
    return digest.hexdigest()


def bind(modules: Sequence[ModuleType]) -> int:
    """Check each cached kernel defined in ``modules`` against :func:`unit_stamp` of them all
    (before any of them compiles or loads); returns how many kernels were bound."""
    stamp = unit_stamp(modules)
    bound = 0
    for module in modules:
        for obj in vars(module).values():
            if not (isinstance(obj, Dispatcher) and obj.py_func.__module__ == module.__name__):
                continue
            kernel: Any = obj
            cache = getattr(kernel, "_cache", None)
            index = getattr(cache, "_cache_file", None)
            if index is not None and hasattr(index, "_source_stamp"):
                index._source_stamp = stamp
                bound += 1
            elif cache is not None and not isinstance(cache, NullCache):
                warnings.warn(f"{obj.py_func.__qualname__}: this numba's cache cannot be checked "
                              "against the kernels' unit; compiled without it", stacklevel=2)
                kernel._cache = NullCache()
    return bound
