"""Compiled code for the per-scan hot path: Numba's ``njit`` with the project's options, and
the fused multiply-add that the kernels need to reproduce a matrix product exactly.

Kernels are compiled on their first call and cached on disk beside the module (``cache=True``),
so only the first run after an install pays the compilation; :func:`houghloc.warm_up.warm_up`
compiles them all ahead of a stream (``houghloc`` calls it before the first scan of a run).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ParamSpec, TypeVar

import numba
from numba.core import types
from numba.core.extending import intrinsic

# cache: compiled once per install; nogil: the sweep's threads and a node's callbacks overlap;
# error_model="numpy": a division by zero is inf/NaN as in NumPy (the kernels test for it), not
# an exception raised from compiled code.
njit: Callable[..., Any] = numba.njit(cache=True, nogil=True, error_model="numpy")


if TYPE_CHECKING:  # what the kernels call; Numba types the intrinsic below

    def fma(a: float, b: float, c: float) -> float: ...

else:

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


P = ParamSpec("P")
R = TypeVar("R")
_blas_libraries: list[Any] | None = None  # threadpoolctl's controllers of the loaded BLAS


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with NumPy's BLAS on one thread (threadpoolctl).

    Global matching's arrays are small: OpenBLAS's threads gain nothing on them, and spin on
    the other cores while they wait (measured on 2 cores: a held-out Freiburg 079 replay spent
    53 s of CPU in 48 s of wall time with no limit, 42 s in 42 s with these steps limited).
    The manager's global steps (collecting views, the local re-search) are so decorated; a
    tracking scan does no BLAS work that spawns threads, and pays nothing. Only the decorated
    calls are limited; the rest of the process keeps its threads. The libraries' controllers
    are found once and set directly: threadpoolctl's ``limit`` context looks them up on every
    call (30 µs against 12 µs)."""

    @functools.wraps(function)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        global _blas_libraries
        if _blas_libraries is None:
            from threadpoolctl import ThreadpoolController

            _blas_libraries = ThreadpoolController().select(user_api="blas").lib_controllers
        before = [library.num_threads for library in _blas_libraries]
        if all(n == 1 for n in before):
            return function(*args, **kwargs)
        for library in _blas_libraries:
            library.set_num_threads(1)
        try:
            return function(*args, **kwargs)
        finally:
            for library, n in zip(_blas_libraries, before, strict=True):
                library.set_num_threads(n)

    return limited
