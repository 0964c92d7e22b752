"""Reader for the Intel Research Lab ``scan_intel.mat`` (raw scans and raw wheel odometry).

Variables: ``beam_data`` N×n ranges in metres (81.83 = no return), ``odom`` N×3 raw odometry
(x, y, θ) in the odometry frame, ``timestamp`` N×1 seconds, ``beam_start``/``beam_end`` the first
and last beam angles, ``beam_n`` the beam count. Beam i is at
``linspace(beam_start, beam_end, n)[i]``, as the file's own variables say.

Rows are in acquisition order (odometry and scans change smoothly from row to row) but 323 of the
5505 stamps are out of order (e.g. 32.648, 33.108, 32.907: the middle one is late). Each row's
odometry belongs to its scan, so the filter must see the rows in order: rows off the longest
non-decreasing run of stamps get a time interpolated between their in-order neighbours, and their
own stamp goes to ``Scan.stamp`` (outputs are written at it; references and relations use it).
Fed to a time-ordered filter as they were, such rows had their odometry dropped as "backwards" and
their scan matched at odometry interpolated at the wrong time (up to 7° off while turning).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.events import Event, Odometry, ReadStats, Scan
from fusion.io.carmen import NO_RETURN_RANGE
from fusion.io.errors import LogError

# The .mat marks "no return" by 81.83; ranges at or above NO_RETURN_RANGE are treated as such.


@dataclass
class IntelMatLog:
    """The arrays of an Intel ``.mat`` file; iterating yields ``Odometry`` then ``Scan`` per row."""

    path: Path
    t: NDArray[np.float64]
    odom: NDArray[np.float64]
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    no_return_range: float = NO_RETURN_RANGE
    stats: ReadStats = field(default_factory=ReadStats)

    def __len__(self) -> int:
        return len(self.t)

    def __iter__(self) -> Iterator[Event]:
        self.stats.records = self.stats.skipped = 0
        self.stats.warnings.clear()
        self.stats.backwards_timestamps = int(np.count_nonzero(np.diff(self.t) < 0))
        in_order = in_order_times(self.t)
        finite = (np.isfinite(self.odom).all(axis=1) & np.isfinite(in_order)).tolist()
        for i, t in enumerate(in_order.tolist()):
            x, y, theta = self.odom[i].tolist()
            if not finite[i]:
                self.stats.warn(f"row {i + 1}: non-finite odometry or time, skipped")
                continue
            self.stats.records += 1
            # Odometry first: the localizer then predicts to the scan's time before the update.
            yield Odometry(t, x, y, theta)
            stamp = float(self.t[i]) if t != self.t[i] else None
            yield Scan(t, self.ranges[i], self.angles, max_range=self.no_return_range, line=i + 1,
                       stamp=stamp)


def in_order_times(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Stamps of rows known to be in order, made non-decreasing with the fewest changes: rows on
    a longest non-decreasing subsequence keep their stamp, the others are interpolated (by row)
    between the kept ones around them. Non-finite stamps are left as they are."""
    t = np.asarray(t, dtype=float)
    finite = np.flatnonzero(np.isfinite(t))
    if len(finite) < 2 or (np.diff(t[finite]) >= 0).all():
        return t
    tails: list[float] = []  # patience sort: tails[k] = smallest end of a run of length k + 1
    tail_row: list[int] = []
    prev = np.full(len(t), -1)
    for i in finite.tolist():
        k = bisect_right(tails, t[i])
        if k == len(tails):
            tails.append(t[i])
            tail_row.append(i)
        else:
            tails[k], tail_row[k] = t[i], i
        prev[i] = tail_row[k - 1] if k else -1
    chain = []
    i = tail_row[-1]
    while i >= 0:
        chain.append(i)
        i = prev[i]
    keep = np.array(chain[::-1])
    out = t.copy()
    out[finite] = np.interp(finite, keep, t[keep])
    return out


def read_intel_mat(path: str | Path, no_return_range: float = NO_RETURN_RANGE) -> IntelMatLog:
    """Load ``scan_intel.mat`` (MATLAB v5, via ``scipy.io.loadmat``). Raises ``LogError`` when the
    file is missing, not a MATLAB file, or lacks a variable or has inconsistent shapes."""
    from scipy.io import loadmat  # scipy is heavy; import it only when a .mat is read

    path = Path(path)
    if not path.is_file():
        raise LogError(path, "file not found")
    try:
        mat = loadmat(path)
    except Exception as err:  # scipy raises ValueError, TypeError, MatReadError… for bad files
        raise LogError(path, f"not a readable MATLAB file ({err})") from None
    missing = [k for k in ("beam_data", "odom", "timestamp") if k not in mat]
    if missing:
        raise LogError(path, f"missing variable(s) {', '.join(missing)}")
    ranges = np.asarray(mat["beam_data"], dtype=float)
    odom = np.asarray(mat["odom"], dtype=float)
    t = np.asarray(mat["timestamp"], dtype=float).ravel()
    if ranges.ndim != 2 or odom.shape != (len(ranges), 3) or t.shape != (len(ranges),):
        raise LogError(
            path,
            f"inconsistent shapes: beam_data {ranges.shape}, odom {odom.shape}, "
            f"timestamp {t.shape}",
        )
    n = ranges.shape[1]
    start = float(np.ravel(mat.get("beam_start", -np.pi / 2))[0])
    end = float(np.ravel(mat.get("beam_end", np.pi / 2))[0])
    if "beam_n" in mat and int(np.ravel(mat["beam_n"])[0]) != n:
        raise LogError(path, f"beam_n = {int(np.ravel(mat['beam_n'])[0])} but beam_data has {n}")
    angles = np.linspace(start, end, n)
    angles.flags.writeable = False
    return IntelMatLog(path, t, odom, ranges, angles, float(no_return_range))
