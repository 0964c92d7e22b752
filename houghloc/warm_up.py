"""Every compiled kernel of the per-scan path compiled, or loaded from Numba's cache, before the
first scan of a stream, so that no scan pays for it. It exercises the whole package, so it sits
above every other module of it (nothing of ``houghloc`` imports it).
"""

from __future__ import annotations

import time

import numpy as np

from houghloc.config import HoughConfig
from houghloc.geometry import (
    positive_definite,
    ranges_to_points,
    ray_segment_distances,
    within_range,
)
from houghloc.global_match import global_match
from houghloc.localize import localize_scan, observe_lines
from houghloc.map_lookup import wall_cells, wall_distance
from houghloc.neighbourhood import Neighbourhood
from houghloc.polish import polish_pose
from houghloc.segment_map import SegmentMap

_warmed_up: float | None = None


def warm_up() -> float:
    """Compile every kernel of the per-scan path, or load it from the cache, before the first
    scan: a synthetic scan of a synthetic room is turned into points, localized (its map models
    one wall by two pieces 15 cm apart, so a line fits two map lines and the second matching
    pass runs), its guess polished on its points, matched globally and scored; a view of a
    corridor is matched globally, which only the slide along its walls can place. Once per
    process; returns the seconds it took (0 when already done).

    A kernel is compiled the first time it is called with new argument types; the kernels'
    callers pass one layout (C-contiguous float64), so this one pass covers a whole run: no
    kernel is compiled, or loaded, on a scan of the stream (``tests/test_fusion.py``).
    """
    global _warmed_up
    if _warmed_up is not None:
        return 0.0
    started = time.perf_counter()
    corners = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])
    starts = np.vstack((corners, [[3.0, 2.5]]))
    ends = np.vstack((np.roll(corners, -1, axis=0), [[3.0, 4.0]]))
    room = SegmentMap(np.vstack((starts, [[0.5, 3.85]])), np.vstack((ends, [[5.5, 3.85]])),
                      ["wall"] * 6)
    pose = np.array([2.0, 1.5, 0.3])
    bearings = np.linspace(-np.pi, np.pi, 181)[:-1]
    dirs = np.column_stack((np.cos(bearings + pose[2]), np.sin(bearings + pose[2])))
    ranges = ray_segment_distances(pose[:2], dirs, starts, ends).min(axis=1)
    points = ranges_to_points(ranges, bearings)
    frozen_ranges, frozen_bearings = ranges.copy(), bearings.copy()  # a stream's beam angles are
    frozen_ranges.flags.writeable = frozen_bearings.flags.writeable = False  # often read-only
    for beams in ((frozen_ranges, bearings), (ranges, frozen_bearings),
                  (frozen_ranges, frozen_bearings)):
        ranges_to_points(*beams)
    guess = pose + np.array([0.05, -0.05, 0.02])
    localize_scan(points, room, guess)  # the default prior: a read-only array
    localize_scan(points, room, guess, pose_cov=np.diag([0.04, 0.04, 0.003]))
    config = HoughConfig()  # the guess polished on the points in every direction (a refused fix)
    polish_pose(points, None, wall_cells(room, config.reference_kinds, config.polish_gate or 0.12),
                guess, np.eye(3), config)
    lines = observe_lines(points, HoughConfig())[2]
    global_match(lines, points, room)
    global_match(lines, points, room, near=Neighbourhood(pose, 1.0, 0.3))
    corridor = SegmentMap(np.array([[0.0, 0.0], [0.0, 2.0]]), np.array([[20.0, 0.0], [20.0, 2.0]]),
                          ["wall"] * 2)
    along = ray_segment_distances(np.array([5.0, 1.0]), np.column_stack((
        np.cos(bearings), np.sin(bearings))), corridor.starts, corridor.ends).min(axis=1)
    view = ranges_to_points(along, bearings, 8.0)
    view_lines = observe_lines(view, HoughConfig())[2]
    localize_scan(view, corridor, np.array([5.03, 0.98, 0.01]))  # a rank-2 fix, polished
    global_match(view_lines, view, corridor)
    global_match(view_lines, view, corridor, near=Neighbourhood(np.array([5.0, 1.0, 0.0]), 1.0,
                                                                 0.3))
    positive_definite(np.eye(3))
    within_range(points, 3.0)
    walls = wall_distance(room, ("wall",), 0.05)
    for smooth in (False, True):
        walls.at(pose[None, :], points[:, 0], points[:, 1], smooth)
        walls.closeness(pose[None, :], points[:, 0], points[:, 1], 0.12, smooth)
    walls.on_walls(pose[None, :], points[:, 0], points[:, 1], 0.12)
    _warmed_up = time.perf_counter() - started
    return _warmed_up
