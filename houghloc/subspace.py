"""Small dense algebra in the directions a fix observed (the Gauss–Newton step of
:mod:`houghloc.polish`), compiled: B m Bᵀ, BᵀHB and Bᵀg for a 3×k basis B of orthonormal
columns, whether a k×k information matrix pins every direction, and its Cholesky solve.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from houghloc.jit import njit

MIN_CONDITION = 1e-12
"""Smallest eigenvalue of BᵀHB over its largest below which the scan's points do not pin the pose
in every direction the fix observed: the fix is left as it is."""


@njit
def expand(basis: NDArray, m: NDArray) -> NDArray:
    """B m Bᵀ (3×3) of a k×k ``m``."""
    k = basis.shape[1]
    out = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for a in range(k):
                for b in range(k):
                    out[i, j] += basis[i, a] * m[a, b] * basis[j, b]
    return out


@njit
def project(basis: NDArray, H: NDArray, out: NDArray) -> None:
    """BᵀHB into ``out`` (k×k)."""
    k = basis.shape[1]
    for a in range(k):
        for b in range(k):
            total = 0.0
            for i in range(3):
                row = 0.0
                for j in range(3):
                    row += H[i, j] * basis[j, b]
                total += basis[i, a] * row
            out[a, b] = total


@njit
def project_vector(basis: NDArray, g: NDArray) -> NDArray:
    """Bᵀg."""
    k = basis.shape[1]
    out = np.zeros(k)
    for a in range(k):
        for i in range(3):
            out[a] += basis[i, a] * g[i]
    return out


@njit
def well_conditioned(m: NDArray) -> bool:
    """Smallest eigenvalue of the symmetric positive semi-definite ``m`` (2×2 or 3×3) over its
    largest above ``MIN_CONDITION``. The usual case is decided without eigenvalues: λ_min/λ_max
    ≥ det / λ_max^k ≥ det / trace^k, and det's rounding is a thousandth of the bound tested (a
    margin of ten covers it). Otherwise LAPACK's eigenvalues decide."""
    k = m.shape[0]
    trace = 0.0
    for i in range(k):
        trace += m[i, i]
    if k == 2:
        det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    else:
        det = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
               - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
               + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
    if trace > 0.0 and det > 10.0 * MIN_CONDITION * trace**k:
        return True
    eig = np.linalg.eigvalsh(m)
    return bool(eig[0] > MIN_CONDITION * eig[-1])


@njit
def solve_spd(m: NDArray, rhs: NDArray) -> NDArray:
    """x with m x = rhs, m symmetric positive definite (k ≤ 3): Cholesky, m = LLᵀ."""
    k = m.shape[0]
    low = np.zeros((k, k))
    for j in range(k):
        diagonal = m[j, j]
        for c in range(j):
            diagonal -= low[j, c] * low[j, c]
        low[j, j] = math.sqrt(diagonal)
        for i in range(j + 1, k):
            value = m[i, j]
            for c in range(j):
                value -= low[i, c] * low[j, c]
            low[i, j] = value / low[j, j]
    x = rhs.copy()
    for i in range(k):  # L y = rhs
        for c in range(i):
            x[i] -= low[i, c] * x[c]
        x[i] /= low[i, i]
    for i in range(k - 1, -1, -1):  # Lᵀ x = y
        for c in range(i + 1, k):
            x[i] -= low[c, i] * x[c]
        x[i] /= low[i, i]
    return x
