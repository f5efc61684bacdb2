"""Read-only views for the compiled kernels' inputs.

numba compiles one machine-code version of a kernel per argument *type*, and an array's type
includes whether it is writable: a read-only array (a ``np.broadcast_to`` view, a forest tile
mapped read-only from shared memory, a cached table) and a writable one of the same shape and
dtype are two types. A kernel warmed up with one and called with the other compiles again at
that call, holding the interpreter for a fraction of a second: in a node's loop, a stall. The
wrappers around the kernels (:mod:`sim_core.flight`, :mod:`sim_core.sonar.precull`,
:mod:`sim_core.world.ball`) therefore pass every array a kernel only reads that comes from
their caller as a read-only view (:func:`readonly`, no copy; the scratch arrays a wrapper makes
itself are always writable and passed as they are), so each kernel has one input type whatever
the caller held, and the version their ``warm_up`` compiles is the one every later call uses.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

__all__ = ["readonly"]

A = TypeVar("A", bound=np.ndarray)


def readonly(a: A) -> A:
    """A read-only view of ``a`` (the same memory; ``a`` itself is unchanged), or ``a`` when it
    is read-only already (most kernel inputs are: ``broadcast_to`` views, cached tables)."""
    if not a.flags.writeable:
        return a
    v = a.view()
    v.flags.writeable = False
    return v
