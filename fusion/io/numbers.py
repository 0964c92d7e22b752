"""Decimal numbers parsed many at a time: a log's record holds hundreds of ranges.

``float(text)`` costs about 0.2 µs a number in CPython; a scan's 361 ranges took a third of a
replay's time outside the localizer. :func:`parse_floats` reads all of a record's numbers in
one compiled pass, exactly as ``float`` would: a decimal of at most 15 significant digits and a
power of ten up to 10²² is the quotient (or product) of two exactly representable doubles, which
IEEE arithmetic rounds correctly (Clinger's fast path). Anything else (more digits, an exponent,
``nan``, ``inf``, a malformed token) is left to ``float``, token by token.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from houghloc.jit import njit

_POWERS_OF_TEN = np.array([10.0**k for k in range(23)])  # all exact in a double


def parse_floats(tokens: list[str]) -> NDArray[np.float64]:
    """The numbers written in ``tokens``, as ``np.array(tokens, dtype=float)`` gives them.
    Raises ``ValueError`` naming the first token that is not a number."""
    values, exact = _parse(" ".join(tokens).encode("ascii", "replace"), len(tokens),
                           _POWERS_OF_TEN)
    if not exact.all():
        for i in np.flatnonzero(~exact):
            values[i] = float(tokens[i])  # the rare forms; raises on a malformed one
    return values


@njit
def _parse(text: bytes, count: int, powers: NDArray) -> tuple[NDArray, NDArray]:
    """``count`` space-separated decimals [−]digits[.digits]; ``exact[i]`` is False where the
    fast path does not apply (the value is then left at 0)."""
    values = np.zeros(count)
    exact = np.zeros(count, np.bool_)
    n, pos = len(text), 0
    for i in range(count):
        while pos < n and text[pos] == 32:
            pos += 1
        negative = pos < n and text[pos] == 45  # '-'
        if negative or (pos < n and text[pos] == 43):  # '+'
            pos += 1
        mantissa, digits, decimals, seen_point, ok = 0, 0, 0, False, True
        start = pos
        while pos < n and text[pos] != 32:
            c = text[pos]
            if 48 <= c <= 57:
                if mantissa > 0 or c != 48:
                    digits += 1
                mantissa = mantissa * 10 + (c - 48) if digits <= 15 else mantissa
                if seen_point:
                    decimals += 1
            elif c == 46 and not seen_point:  # '.'
                seen_point = True
            else:
                ok = False
            pos += 1
        if not ok or pos == start or digits > 15 or decimals > 22 or (
                pos - start == 1 and seen_point):
            continue
        value = mantissa / powers[decimals]
        values[i] = -value if negative else value
        exact[i] = True
    return values, exact
