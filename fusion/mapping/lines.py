"""Wall lines as arrays (end points, direction, normal), their total-least-squares moments
(merged by adding), and the geometry the map builder's stages share.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from houghloc.refine import tls_fit
from houghloc.segment_map import SegmentMap


@dataclass(frozen=True)
class WallLines:
    """Fitted lines: a point on each, its unit direction, and an extent [s0, s1] along it
    (measured from ``point``)."""

    point: NDArray[np.float64]
    direction: NDArray[np.float64]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.column_stack((-self.direction[:, 1], self.direction[:, 0]))

    @property
    def starts(self) -> NDArray[np.float64]:
        return self.point + self.s0[:, None] * self.direction

    @property
    def ends(self) -> NDArray[np.float64]:
        return self.point + self.s1[:, None] * self.direction

    @property
    def length(self) -> NDArray[np.float64]:
        return self.s1 - self.s0

    def __len__(self) -> int:
        return len(self.point)


def walls_longest_first(starts: NDArray[np.float64], ends: NDArray[np.float64],
                         name: str) -> SegmentMap:
    """The wall map of these segments, longest first, with ids w0, w1, ... in that order."""
    order = np.argsort(-np.linalg.norm(ends - starts, axis=1), kind="stable")
    return SegmentMap(starts[order], ends[order], kinds=["wall"] * len(order),
                      ids=[f"w{i}" for i in range(len(order))], name=name)


def lines_from_ends(a: NDArray[np.float64], b: NDArray[np.float64]) -> WallLines:
    length = np.linalg.norm(b - a, axis=1)
    direction = (b - a) / np.maximum(length, 1e-12)[:, None]
    return WallLines(a, direction, np.zeros(len(a)), length)


@dataclass(frozen=True)
class Moments:
    """Point counts, sums and second moments per line: a total-least-squares fit in closed form
    that can be merged by adding."""

    n: NDArray[np.float64]
    sx: NDArray[np.float64]
    sy: NDArray[np.float64]
    sxx: NDArray[np.float64]
    sxy: NDArray[np.float64]
    syy: NDArray[np.float64]

    @classmethod
    def of(cls, labels: NDArray[np.intp], xy: NDArray[np.float64], count: int) -> Moments:
        x, y = xy[:, 0], xy[:, 1]

        def total(weights: NDArray[np.float64] | None) -> NDArray[np.float64]:
            return np.bincount(labels, weights=weights, minlength=count).astype(float)

        return cls(total(None), total(x), total(y), total(x * x), total(x * y), total(y * y))

    def fit(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centroid and principal direction per line (where n ≥ 2): the Hough method's
        total-least-squares fit (:func:`houghloc.refine.tls_fit`)."""
        sums = np.vstack((self.n, self.sx, self.sy, self.sxx, self.sxy, self.syy))
        *_, centroid, _spread, phi = tls_fit(sums)
        return centroid.T.copy(), np.column_stack((np.cos(phi), np.sin(phi)))


def on_group_line(a: NDArray[np.float64], b: NDArray[np.float64], d: NDArray[np.float64],
                   point: NDArray[np.float64], direction: NDArray[np.float64], cos_tol: float,
                   offset_tol: float) -> NDArray[np.bool_]:
    """Per group (a line through ``point`` along ``direction``): does the segment a–b of
    direction d lie on it, its direction within the angle whose cosine is ``cos_tol`` and both
    its ends within ``offset_tol``?"""
    normal = np.column_stack((-direction[:, 1], direction[:, 0]))
    off_a = np.abs(np.einsum("ij,ij->i", a - point, normal))
    off_b = np.abs(np.einsum("ij,ij->i", b - point, normal))
    return (np.abs(direction @ d) >= cos_tol) & (off_a <= offset_tol) & (off_b <= offset_tol)


def gap_to_extent(a: NDArray[np.float64], b: NDArray[np.float64], point: NDArray[np.float64],
                   direction: NDArray[np.float64], extent: NDArray[np.float64]
                   ) -> NDArray[np.float64]:
    """Per group: the gap along its line between the segment a–b and the group's extent [s0, s1]
    (negative where they overlap)."""
    sa = np.einsum("ij,ij->i", a - point, direction)
    sb = np.einsum("ij,ij->i", b - point, direction)
    return np.maximum(np.minimum(sa, sb) - extent[:, 1], extent[:, 0] - np.maximum(sa, sb))


def end_moments(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Moments of a segment as a uniform distribution of mass 1 along it (not just its ends):
    the covariance of a uniform segment is ``(b − a)(b − a)ᵀ/12`` about its midpoint."""
    m = 0.5 * (a + b)
    d = b - a
    return np.array([1.0, m[0], m[1], m[0] * m[0] + d[0] * d[0] / 12,
                     m[0] * m[1] + d[0] * d[1] / 12, m[1] * m[1] + d[1] * d[1] / 12])


def fit_moments(mom: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    centroid, direction = Moments(*(np.atleast_1d(v) for v in mom)).fit()
    return centroid[0], direction[0]
