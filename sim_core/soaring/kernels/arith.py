"""The soaring kernels' scalar arithmetic, evaluated as GNU Octave evaluates the seed's MATLAB
(:mod:`sim_core.soaring.kernels`), and :data:`jit`, the compiler every kernel goes through.

``norm`` of a vector is Octave's scaled 2-norm (:func:`norm2`, :func:`norm3`), a scalar ``x^p``
is libm's ``pow`` (:data:`spow`) and an elementwise ``.^`` follows Octave's special cases
(:func:`epow`), ``dot`` is the fused multiply-add of the reference run's BLAS (:data:`fma`);
:func:`minimum`, :func:`maximum` and :func:`sign` keep numpy's NaN rules, :func:`round_half_away`
is C's ``round``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: numba's ``njit`` as the kernels use it: cached on disk (:mod:`sim_core.soaring.kernels.cache`),
#: numpy's error model (a division by zero gives inf or NaN, as in Octave), no fast-math
jit = njit(cache=True, error_model="numpy")


def _fma(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.fma(*args)

    return types.float64(types.float64, types.float64, types.float64), codegen


def _spow(typingctx: Any, x: Any, y: Any) -> Any:
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        dbl = ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(dbl, [dbl, dbl]),
                                            "pow")
        fn.attributes.add("nobuiltin")
        return builder.call(fn, args)

    return types.float64(types.float64, types.float64), codegen


#: fma(a, b, c) = a·b + c with one rounding (llvm.fma: the CPU's instruction, or libm's fma).
fma: Any = intrinsic(_fma)
#: spow(x, y): libm ``pow`` as called, never rewritten by the optimiser (which turns
#: pow(x, 2.0) into x·x; glibc's pow rounds that differently about once in a thousand):
#: Octave's scalar ``x^y``.
spow: Any = intrinsic(_spow)


@jit
def epow(x: float, e: float, count: int) -> float:
    """Element of Octave's ``v.^e`` for a vector v of ``count`` elements: a 1-element v is a
    scalar (``pow``); otherwise integer e = 2, 3, −1 are products or 1/x, the rest ``pow``."""
    if count != 1:
        if e == 2.0:
            return x * x
        if e == 3.0:
            return x * x * x
        if e == -1.0:
            return 1.0 / x
    return spow(x, e)


@jit
def _accum(scl: float, ssq: float, v: float) -> tuple[float, float]:
    t = abs(v)
    if scl == t:
        ssq += 1.0
    elif scl < t:
        r = scl / t
        ssq *= r * r
        ssq += 1.0
        scl = t
    elif t != 0.0:
        r = t / scl
        ssq += r * r
    return scl, ssq


@jit
def norm2(a: float, b: float) -> float:
    """Octave's ``norm([a b])``: the scaled sum of squares, scl·sqrt(ssq)."""
    scl, ssq = _accum(0.0, 1.0, a)
    scl, ssq = _accum(scl, ssq, b)
    return scl * math.sqrt(ssq)


@jit
def norm3(a: float, b: float, c: float) -> float:
    """Octave's ``norm([a b c])``."""
    scl, ssq = _accum(0.0, 1.0, a)
    scl, ssq = _accum(scl, ssq, b)
    scl, ssq = _accum(scl, ssq, c)
    return scl * math.sqrt(ssq)


@jit
def round_half_away(x: float) -> float:
    """C ``round``: halves away from zero."""
    r = np.floor(abs(x))
    if abs(x) - r >= 0.5:
        r += 1.0
    return -r if x < 0.0 else r


@jit
def minimum(a: float, b: float) -> float:
    return a if (a <= b or a != a) else b


@jit
def maximum(a: float, b: float) -> float:
    return a if (a >= b or a != a) else b


@jit
def sign(a: float) -> float:
    if a > 0.0:
        return 1.0
    if a < 0.0:
        return -1.0
    return 0.0 if a == 0.0 else a
