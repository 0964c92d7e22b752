"""nav2's AMCL as the benchmark's peer: nav2_amcl's own particle filter and sensor models, driven
as nav2's ``amcl_node`` drives them (:class:`Nav2Amcl`).

The filter is nav2_amcl's C and C++ code (``pf``, ``map``, the motion and laser models, LGPL-2.1;
the copy in the ``amcl`` package's source distribution on PyPI) compiled with a small C
interface of houghloc's (``binding.cpp``) into a library of this environment::

    python -m fusion.bench.nav2_amcl

which ``make setup`` runs. The interface adds what nav2's node adds around the filter and the
``amcl`` wheel lacks: the likelihood field model (nav2's default), the pose of the heaviest
cluster rather than the mean of every particle, global localization over the map's free cells,
and a fixed seed.
"""

from __future__ import annotations

import ctypes
import math
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

LIBRARY = Path(sys.prefix) / "lib" / "houghloc" / "libnav2_amcl.so"
"""Where ``python -m fusion.bench.nav2_amcl`` puts the compiled filter."""


class Nav2AmclUnavailable(RuntimeError):
    """The compiled filter is not in this environment; the text says how to build it."""


_double_p = ctypes.POINTER(ctypes.c_double)


def _library() -> ctypes.CDLL:
    if not LIBRARY.exists():
        raise Nav2AmclUnavailable(
            f"nav2's AMCL is not built in this environment ({LIBRARY} is missing): "
            "run `python -m fusion.bench.nav2_amcl` (make setup does)")
    lib = ctypes.CDLL(str(LIBRARY))
    lib.hl_amcl_new.restype = ctypes.c_void_p
    lib.hl_amcl_new.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double,
                                ctypes.c_double, ctypes.c_double, _double_p, ctypes.c_int,
                                ctypes.c_int, ctypes.c_long]
    lib.hl_amcl_free.argtypes = [ctypes.c_void_p]
    lib.hl_amcl_set_map.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int,
                                    ctypes.c_double, ctypes.c_double, ctypes.c_double,
                                    ctypes.POINTER(ctypes.c_int8), ctypes.c_int, _double_p,
                                    ctypes.c_int]
    lib.hl_amcl_set_laser_pose.argtypes = [ctypes.c_void_p] + [ctypes.c_double] * 3
    lib.hl_amcl_init_pose.argtypes = [ctypes.c_void_p, _double_p, _double_p]
    lib.hl_amcl_init_global.argtypes = [ctypes.c_void_p]
    lib.hl_amcl_update.argtypes = [ctypes.c_void_p, _double_p, ctypes.c_int, _double_p,
                                   ctypes.c_double]
    lib.hl_amcl_estimate.argtypes = [ctypes.c_void_p, _double_p, _double_p]
    lib.hl_amcl_particles.argtypes = [ctypes.c_void_p, _double_p, ctypes.c_int]
    return lib


def _doubles(a: NDArray[np.float64]) -> ctypes._Pointer[ctypes.c_double]:
    return a.ctypes.data_as(_double_p)


class Nav2Amcl:
    """One nav2_amcl particle filter. ``alpha`` are nav2's ``alpha1``–``alpha5``; ``model``
    is ``"likelihood_field"`` (nav2's default) or ``"beam"``; ``laser`` holds nav2's
    ``z_hit, z_short, z_max, z_rand, sigma_hit, lambda_short, chi_outlier,
    laser_likelihood_max_dist`` by those names."""

    def __init__(self, *, min_particles: int, max_particles: int, alpha_slow: float,
                 alpha_fast: float, alpha: tuple[float, ...], pf_err: float = 0.05,
                 pf_z: float = 0.99, omni: bool = False, resample_interval: int = 1,
                 seed: int = 0) -> None:
        self._lib = _library()
        a = np.ascontiguousarray(alpha, dtype=float)
        if a.shape != (5,):
            raise ValueError("alpha: nav2's five motion noise parameters")
        self._handle = self._lib.hl_amcl_new(min_particles, max_particles, alpha_slow,
                                             alpha_fast, pf_err, pf_z, _doubles(a), int(omni),
                                             resample_interval, seed)
        self.max_particles = max_particles

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle:
            self._lib.hl_amcl_free(handle)
            self._handle = None

    def set_map(self, data: NDArray[np.int8], resolution: float, origin: tuple[float, float],
                model: str, laser: dict[str, float], max_beams: int) -> None:
        """``data``: the grid as ``nav_msgs/OccupancyGrid`` holds it, rows of y, 0 free,
        100 occupied; the likelihood field is computed here, as nav2 does on a new map."""
        grid = np.ascontiguousarray(data, dtype=np.int8)
        rows, cols = grid.shape
        params = np.array([laser[k] for k in ("z_hit", "z_short", "z_max", "z_rand", "sigma_hit",
                                               "lambda_short", "chi_outlier",
                                               "laser_likelihood_max_dist")], dtype=float)
        if model not in ("likelihood_field", "beam"):
            raise ValueError(f"laser model {model!r}: likelihood_field or beam")
        if self._lib.hl_amcl_set_map(self._handle, cols, rows, resolution, origin[0], origin[1],
                                     grid.ctypes.data_as(ctypes.POINTER(ctypes.c_int8)),
                                     int(model == "beam"), _doubles(params), max_beams):
            raise MemoryError("nav2_amcl could not allocate the map")

    def set_laser_pose(self, mount: NDArray[np.float64]) -> None:
        if self._lib.hl_amcl_set_laser_pose(self._handle, *map(float, mount)):
            raise RuntimeError("set the map before the laser's pose")

    def init_pose(self, mean: NDArray[np.float64], cov: NDArray[np.float64]) -> None:
        m = np.ascontiguousarray(mean, dtype=float)
        c = np.ascontiguousarray(cov, dtype=float).reshape(9)
        self._lib.hl_amcl_init_pose(self._handle, _doubles(m), _doubles(c))

    def init_global(self) -> None:
        if self._lib.hl_amcl_init_global(self._handle):
            raise RuntimeError("global localization needs a map with free cells")

    def update(self, odom: NDArray[np.float64], ranges: NDArray[np.float64],
               bearings: NDArray[np.float64], range_max: float) -> None:
        """One nav2 update: motion to ``odom`` (the odometry frame's pose), the scan's weights,
        resampling. Ranges that are not finite are passed as ``range_max`` (ignored)."""
        r = np.where(np.isfinite(ranges), ranges, range_max)
        pairs = np.ascontiguousarray(np.column_stack((r, bearings)), dtype=float)
        o = np.ascontiguousarray(odom, dtype=float)
        if self._lib.hl_amcl_update(self._handle, _doubles(o), len(pairs), _doubles(pairs),
                                    range_max):
            raise RuntimeError("set the map before updating")

    def estimate(self) -> tuple[NDArray[np.float64], NDArray[np.float64], bool]:
        """The heaviest cluster's mean, the particles' covariance, and whether any cluster
        had weight (nav2 publishes nothing when none has)."""
        mean, cov = np.zeros(3), np.zeros(9)
        empty = self._lib.hl_amcl_estimate(self._handle, _doubles(mean), _doubles(cov))
        mean[2] = math.remainder(mean[2], math.tau)
        return mean, cov.reshape(3, 3), not empty

    def particles(self) -> NDArray[np.float64]:
        """The samples as rows (x, y, yaw, weight)."""
        out = np.zeros((self.max_particles, 4))
        n = self._lib.hl_amcl_particles(self._handle, _doubles(out), self.max_particles)
        return out[:n]
