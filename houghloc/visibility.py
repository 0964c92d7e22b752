"""What a pose sees of the map (:class:`houghloc.segment_map.SegmentMap`): rays cast to the
first wall they hit, the segments near a pose, and the reference points its lines predict — the
compiled kernels behind :meth:`SegmentMap.visible` and :meth:`SegmentMap.references`.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from houghloc.geometry import TWO_PI, bearing_span, ray_hit
from houghloc.jit import njit


@lru_cache(maxsize=8)
def ray_directions(n_rays: int) -> NDArray[np.float64]:
    """Unit vectors of ``n_rays`` rays evenly spaced from angle 0 (R×2, read-only)."""
    phi = np.linspace(0.0, TWO_PI, n_rays, endpoint=False)
    dirs = np.column_stack((np.cos(phi), np.sin(phi)))
    dirs.flags.writeable = False
    return dirs


@njit
def visible_packed(starts: NDArray, ends: NDArray, samples: NDArray, first_sample: NDArray,
                    kind_ok: NDArray, is_wall: NDArray, line_of_segment: NDArray, dirs: NDArray,
                    ox: float, oy: float, near: float, max_range: float
                    ) -> tuple[NDArray[np.int32], float]:
    """:meth:`SegmentMap._visible` without its memo, in one compiled call: of the segments of
    the wanted kinds with a sample within ``near`` of the origin, the walls that are the first
    hit of a ray (:func:`first_hits_and_clearance`) then every other kind, each in the map's
    order; their lines (sorted, each once) and each segment's row among those lines, packed as
    :func:`unpack_visible` reads them; and the distance from the origin to the nearest of
    those walls (inf without one)."""
    cand = segments_near(starts, ends, samples, first_sample, ox, oy, near)
    walls = np.empty(len(cand), np.intp)
    others = np.empty(len(cand), np.intp)
    n_walls = n_others = 0
    for j in cand:
        if not kind_ok[j]:
            continue
        if is_wall[j]:
            walls[n_walls] = j
            n_walls += 1
        else:
            others[n_others] = j
            n_others += 1
    clearance = np.inf
    n_visible = 0
    if n_walls:
        hit, clearance = first_hits_and_clearance(dirs, max_range, starts[walls[:n_walls]],
                                                   ends[walls[:n_walls]], ox, oy)
        for k in range(n_walls):
            if hit[k]:
                walls[n_visible] = walls[k]
                n_visible += 1
    segs = np.concatenate((walls[:n_visible], others[:n_others]))
    line_ids = line_of_segment[segs]
    lines = np.unique(line_ids)
    n_segs, n_lines = len(segs), len(lines)
    packed = np.empty(2 + 2 * n_segs + n_lines, np.int32)
    packed[0], packed[1] = n_segs, n_lines
    packed[2:2 + n_segs] = segs
    packed[2 + n_segs:2 + n_segs + n_lines] = lines
    packed[2 + n_segs + n_lines:] = np.searchsorted(lines, line_ids)
    return packed, clearance


@njit
def first_hits_and_clearance(dirs: NDArray, max_range: float, starts: NDArray, ends: NDArray,
                              ox: float, oy: float) -> tuple[NDArray[np.bool_], float]:
    """Which segments are the nearest hit (within ``max_range``) of at least one of the rays
    ``dirs`` (R×2, evenly spaced from angle 0), and the distance from the origin to the nearest
    segment: the projection of the origin, clamped to the segment.

    Each segment is tried only on the rays within its angular extent seen from the origin, one
    ray wider on each side (the extent's rounding cannot exceed that): a ray outside misses it.
    Segments are taken in order and a ray keeps its nearest hit, the first on a tie: the same
    answer as trying every ray on every segment, in a fraction of the work."""
    n_rays, step = dirs.shape[0], TWO_PI / dirs.shape[0]
    nearest = np.full(n_rays, np.inf)
    first = np.full(n_rays, -1, np.intp)
    for j in range(len(starts)):
        p0x, p0y = starts[j, 0] - ox, starts[j, 1] - oy
        ex, ey = ends[j, 0] - starts[j, 0], ends[j, 1] - starts[j, 1]
        # the rays within its extent (every ray when the origin is on or beside it)
        i0, count = bearing_span(p0x, p0y, ends[j, 0] - ox, ends[j, 1] - oy, step, n_rays)
        for q in range(count):
            i = (i0 + q) % n_rays
            t = ray_hit(dirs[i, 0], dirs[i, 1], p0x, p0y, ex, ey)
            if t < nearest[i] and t <= max_range:
                nearest[i], first[i] = t, j
    hit = np.zeros(len(starts), np.bool_)
    for i in range(n_rays):
        if first[i] >= 0:
            hit[first[i]] = True
    clearance_sq = np.inf
    for j in range(len(starts)):
        clearance_sq = min(clearance_sq, distance_sq(starts, ends, j, ox, oy))
    return hit, math.sqrt(clearance_sq)


@njit
def distance_sq(starts: NDArray, ends: NDArray, j: int, ox: float, oy: float) -> float:
    """Squared distance from (ox, oy) to segment ``j``: to the origin's projection, clamped to
    the segment (its start when the segment has no length)."""
    p0x, p0y = starts[j, 0] - ox, starts[j, 1] - oy
    ex, ey = ends[j, 0] - starts[j, 0], ends[j, 1] - starts[j, 1]
    along = min(max(-(p0x * ex + p0y * ey) / max(ex * ex + ey * ey, 1e-300), 0.0), 1.0)
    qx, qy = p0x + along * ex, p0y + along * ey
    return qx * qx + qy * qy


@njit
def segments_near(starts: NDArray, ends: NDArray, samples: NDArray, first_sample: NDArray,
                   cx: float, cy: float, radius: float) -> NDArray[np.intp]:
    """The segments with a sample point within ``radius`` of (cx, cy). A segment whose nearest
    point is farther has no such sample: its samples are looked at only otherwise (the bound is
    loosened by a relative 1e-9, so that rounding cannot drop a segment with a sample on the
    circle)."""
    r2 = radius * radius
    bound = r2 * (1.0 + 1e-9) + 1e-12
    out = np.empty(len(starts), np.intp)
    count = 0
    for j in range(len(starts)):
        if distance_sq(starts, ends, j, cx, cy) > bound:
            continue
        for k in range(first_sample[j], first_sample[j + 1]):
            dx, dy = samples[k, 0] - cx, samples[k, 1] - cy
            if dx * dx + dy * dy <= r2:
                out[count] = j
                count += 1
                break
    return out[:count]


@njit
def predict_references(line_alpha: NDArray, line_r: NDArray, line_normal: NDArray,
                        seg_s0: NDArray, seg_s1: NDArray, segs: NDArray, lines: NDArray,
                        seg_ref: NDArray, x: float, y: float, th: float) -> tuple:
    """Each line's Hough point seen from (x, y, θ): ρ = r − (x cos α + y sin α); a negative ρ
    means the robot sees the line's normal reversed, β = α + π. θ_r = β − θ. Each segment's
    extent along (−sin β, cos β), which flips with β."""
    n_lines = len(lines)
    theta, rho, beta = np.empty(n_lines), np.empty(n_lines), np.empty(n_lines)
    flipped = np.empty(n_lines, np.bool_)
    for k in range(n_lines):
        m = lines[k]
        signed = line_r[m] - (x * line_normal[0, m] + y * line_normal[1, m])
        flipped[k] = signed < 0
        b = line_alpha[m] + np.pi if flipped[k] else line_alpha[m]
        theta[k], rho[k], beta[k] = (b - th) % TWO_PI, abs(signed), b % TWO_PI
    s0, s1 = np.empty(len(segs)), np.empty(len(segs))
    for q in range(len(segs)):
        sign = -1.0 if flipped[seg_ref[q]] else 1.0
        a, b = seg_s0[segs[q]] * sign, seg_s1[segs[q]] * sign
        s0[q], s1[q] = min(a, b), max(a, b)
    return theta, rho, beta, s0, s1


def unpack_visible(packed: NDArray[np.int32]
                    ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """One memo entry, [n_segs, n_lines, segs…, lines…, seg_ref…] in a single int32 array
    (three arrays would cost three ~100-byte headers for a handful of indices), unpacked."""
    n_segs, n_lines = int(packed[0]), int(packed[1])
    body = packed[2:].astype(np.intp)
    return body[:n_segs], body[n_segs:n_segs + n_lines], body[n_segs + n_lines:]
