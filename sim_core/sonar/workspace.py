"""Scratch memory of the echo synthesis: arrays and finufft plans reused from ping to ping.

Fresh pages cost more than the arithmetic done on them here, and a finufft plan is costly to
make (docs/sonar.md, "Blocks on reused memory"), so the geometry pass, the node weights and the
NUFFTs work in a :class:`Workspace` kept between pings. A workspace serves one echo at a time:
its arrays are valid until the same name is asked for again, and nothing the synthesis returns
aliases them.

A caller that synthesises echoes one after another can own one and pass it in
(``synthesize(..., workspace=ws)``). Otherwise :func:`borrowed` lends one of the process's idle
workspaces for the call and takes it back after: concurrent callers (threads) always get
different ones, without a lock, because taking one off the idle list and putting it back are
single ``list.pop`` / ``list.append`` calls, each atomic. There are as many workspaces as echoes
were ever synthesised at the same time.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from typing import Any

import finufft
import numpy as np
from numpy.typing import DTypeLike, NDArray

__all__ = ["SCRATCH_MAX_BYTES", "Workspace", "borrowed"]

#: scratch arrays larger than this are allocated per call instead of kept (bounds the memory a
#: workspace holds between pings; at this size the page faults are a small share)
SCRATCH_MAX_BYTES = 32 << 20
#: the smallest scratch array kept (small requests then grow it less often)
_MIN_ELEMENTS = 4096


class Workspace:
    """Scratch arrays and cached finufft plans for one echo at a time (see the module)."""

    def __init__(self) -> None:
        self._arrays: dict[tuple[str, np.dtype[Any]], NDArray[Any]] = {}
        self._plans: dict[tuple[int, float, bool, int], Any] = {}

    def array(self, name: str, shape: int | tuple[int, ...], dtype: DTypeLike) -> NDArray[Any]:
        """Scratch array ``name`` of ``shape`` and ``dtype``, contents undefined, valid until
        ``name`` is asked for again with the same dtype (over SCRATCH_MAX_BYTES: a new array)."""
        dt = np.dtype(dtype)
        dims = (shape,) if isinstance(shape, int) else shape
        size = math.prod(dims)
        if size * dt.itemsize > SCRATCH_MAX_BYTES:
            return np.empty(dims, dtype=dt)
        key = (name, dt)
        buf = self._arrays.get(key)
        if buf is None or buf.shape[0] < size:
            buf = np.empty(max(size, _MIN_ELEMENTS), dtype=dt)
            self._arrays[key] = buf
        return buf[:size].reshape(dims)

    def plan(self, modes: int, eps: float, single: bool, n_trans: int) -> Any:
        """A cached finufft type-1 plan for ``n_trans`` transforms onto ``modes`` modes (points
        unsorted: the fine grid of a few thousand points fits in cache, so sorting only costs)."""
        key = (modes, eps, single, n_trans)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = finufft.Plan(
                1, (modes,), n_trans=n_trans, eps=eps, isign=-1, nthreads=1, spread_sort=0,
                dtype="complex64" if single else "complex128",
            )
        return plan


#: workspaces no call holds now
_IDLE: list[Workspace] = []


@contextlib.contextmanager
def borrowed() -> Iterator[Workspace]:
    """An idle workspace of this process (a new one if none is idle) for the ``with`` block,
    idle again after it; no two blocks, in any threads, hold the same one at once."""
    try:
        ws = _IDLE.pop()
    except IndexError:
        ws = Workspace()
    try:
        yield ws
    finally:
        _IDLE.append(ws)
