"""Compiled code for the per-scan hot path: Numba's ``njit`` with the project's options, and
the fused multiply-add that the kernels need to reproduce a matrix product exactly.

Kernels are compiled on their first call and cached on disk beside the module (``cache=True``),
so only the first run after an install pays the compilation; :func:`warm_up` compiles them all
ahead of a stream (``houghloc`` calls it before the first scan of a run).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
from numba.core import types
from numba.core.extending import intrinsic

# cache: compiled once per install; nogil: the sweep's threads and a node's callbacks overlap;
# error_model="numpy": a division by zero is inf/NaN as in NumPy (the kernels test for it), not
# an exception raised from compiled code.
njit: Callable[..., Any] = numba.njit(cache=True, nogil=True, error_model="numpy")


@intrinsic
def fma(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """a·b + c rounded once (IEEE fused multiply-add), in the type of ``a``.

    BLAS computes a two-term product x·c + y·s as fma(y, s, x·c): the kernels that replace such
    a product use the same rounding, so a vote or an inlier test decided at a cell's edge falls
    on the same side as in the matrix form.
    """
    if not (isinstance(a, types.Float) and a == b == c):
        return None
    sig = a(a, b, c)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.fma(*args)

    return sig, codegen
