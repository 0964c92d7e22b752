"""A segment map refitted to the end points of scans placed at their reference poses, band by
narrowing band (walls built from a coarse grid move by a few centimetres onto the points), and
the nearest segment to points.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fusion.mapping.lines import Moments, walls_longest_first
from houghloc.segment_map import SegmentMap

REFIT_BANDS = (0.20, 0.12, 0.08, 0.05, 0.04, 0.04)  # m, one refit pass per band


def refit_to_endpoints(
    segment_map: SegmentMap,
    endpoints: NDArray[np.float64],
    bands: tuple[float, ...] = REFIT_BANDS,
    *,
    min_points: int = 20,
    max_turn: float = math.radians(5.0),
) -> SegmentMap:
    """Stage 7, for wall maps built from scans: every line refitted to the scan endpoints.

    The grid's cells are 5 cm wide and a wall's cells are smeared by furniture standing against
    it, so a line fitted to cells can sit a few centimetres and degrees off the face the laser
    sees. Each pass assigns every endpoint to its nearest segment when it lies within ``band``
    across it and within its extent, refits each line (all segments on it together, so they stay
    collinear) by total least squares to its endpoints, and projects the segments' ends onto
    the refitted line. The bands shrink pass by pass (``bands``), so a line first gathers its
    whole face and then sheds the clutter beside it. A line keeps its place when fewer than
    ``min_points`` endpoints support it or a pass would turn it by more than ``max_turn`` (the
    endpoints then belong to something else). Ids are renumbered longest first.
    """
    if any(kind != "wall" for kind in segment_map.kinds):
        raise ValueError(f"map {segment_map.name!r}: only a map of walls can be refitted to "
                         "scan endpoints (painted lines return none)")
    starts, ends = segment_map.starts.copy(), segment_map.ends.copy()
    line_of = segment_map.line_of_segment
    n_lines = segment_map.n_lines
    min_cos = math.cos(max_turn)
    for band in bands:
        segment, xy = _endpoints_near_segments(starts, ends, endpoints, band)
        moments = Moments.of(line_of[segment], xy, n_lines)
        centroid, direction = moments.fit()
        current = np.zeros((n_lines, 2))
        current[line_of] = (ends - starts) / np.linalg.norm(ends - starts, axis=1)[:, None]
        refit = ((moments.n >= min_points)
                 & (np.abs(np.einsum("ij,ij->i", direction, current)) >= min_cos))[line_of]
        c, d = centroid[line_of[refit]], direction[line_of[refit]]
        for ends_ in (starts, ends):  # orthogonal projection onto the refitted line
            along = np.einsum("ij,ij->i", ends_[refit] - c, d)
            ends_[refit] = c + along[:, None] * d
    return walls_longest_first(starts, ends, segment_map.name)


def nearest_segment(
    starts: NDArray[np.float64], ends: NDArray[np.float64], points: NDArray[np.float64],
    max_distance: float, spacing: float = 0.01,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The points (indices) with a segment within about ``max_distance``, and that nearest
    segment's index for each. The segments are sampled every ``spacing`` into a k-d tree, one
    query for all points: the nearest sample names the segment, whatever the map's size. Every
    point within ``max_distance`` of a segment is found; callers check the exact distance."""
    length = np.linalg.norm(ends - starts, axis=1)
    count = np.ceil(length / spacing).astype(np.intp) + 1
    sample_of = np.repeat(np.arange(len(length)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    samples = starts[sample_of] + (k / (count[sample_of] - 1))[:, None] * (ends - starts)[sample_of]
    near, index = cKDTree(samples).query(points, distance_upper_bound=math.hypot(max_distance,
                                                                                 spacing))
    found = np.flatnonzero(np.isfinite(near))
    return found, sample_of[index[found]]


def _endpoints_near_segments(
    starts: NDArray[np.float64], ends: NDArray[np.float64], endpoints: NDArray[np.float64],
    band: float,
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The endpoints within ``band`` across their nearest segment and within its extent, with
    that segment's index."""
    found, segment = nearest_segment(starts, ends, endpoints, band, spacing=0.02)
    xy = endpoints[found]
    rel, span = xy - starts[segment], ends[segment] - starts[segment]
    length = np.linalg.norm(span, axis=1)
    along = np.einsum("ij,ij->i", rel, span) / length**2
    across = np.abs(rel[:, 0] * span[:, 1] - rel[:, 1] * span[:, 0]) / length
    keep = (along >= 0.0) & (along <= 1.0) & (across <= band)
    return segment[keep], xy[keep]
