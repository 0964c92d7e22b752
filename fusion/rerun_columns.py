"""Rows kept in columns and sent with one ``send_columns`` call per entity (one ``log`` call
costs ~100 µs whatever its size; a row in a batch a few µs): the occasional rows
(:class:`ColumnBatch`), the Hough images (:class:`ImageBatch`), the paths drawn with a number
of entities logarithmic in the run's length, and the error series computed as the truth
arrives. The scans' own rows: :mod:`fusion.rerun_scans`.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr
from numpy.typing import ArrayLike, NDArray

from houghloc.geometry import wrap_angle

# Scans buffered per send_columns call. Each call makes one chunk per entity, and a file sink
# keeps a few kB of metadata per chunk until its footer is written at the end: fewer, larger
# chunks keep a long recording's memory flat.
BATCH_SCANS = 2000
TRUTH_TOLERANCE = 0.5  # s; a truth sample this close stands in for one at the estimate's time
MAX_PENDING_ERRORS = 10 * BATCH_SCANS  # estimates kept waiting for truth that may never come
PATH_PIECE = 50  # poses re-sent at every scan; older ones are re-sent ~log2(n / this) times


class PathPieces:
    """A growing polyline drawn with a bounded number of entities (see the module doc).

    The newest poses (at most ``PATH_PIECE`` segments) are re-sent at every scan on
    ``<entity>/recent``. A full piece moves to level 0; a block arriving on an occupied level
    merges with it (older first) and moves up, as in a binary counter, so level ``j`` holds
    ``2**j`` pieces or nothing. A run of ``n`` poses uses ``1 + log2(n / PATH_PIECE)`` entities
    and re-sends each pose about ``log2(n / PATH_PIECE)`` times.
    """

    def __init__(self, entity: str) -> None:
        self.entity = entity
        self.recent = NO_POINTS  # the newest piece: it starts where the last full one ended
        self.levels: list[NDArray[np.float64] | None] = []

    def extend(self, xy: NDArray[np.float64]
               ) -> tuple[pa.Array, list[tuple[int, str, NDArray[np.float64]]]]:
        """Add poses (their x, y: n×2). Return the newest piece after each pose, as ``n`` line
        strips, and the (pose index, entity, polyline) of the older pieces' changes, an empty
        polyline clearing (they happen with that pose)."""
        done = len(self.recent)
        poses = np.vstack((self.recent, np.asarray(xy, dtype=float).reshape(-1, 2)))
        at = np.arange(done, len(poses))
        # pieces start every PATH_PIECE poses and share their end poses: pose g is in the piece
        # that starts at PATH_PIECE ⌊(g − 1) / PATH_PIECE⌋ (the first pose starts the first)
        starts = np.maximum((at - 1) // PATH_PIECE, 0) * PATH_PIECE
        lengths = at + 1 - starts
        first = np.repeat(starts - (np.cumsum(lengths) - lengths), lengths)
        strips = strips_from_points(poses[first + np.arange(int(lengths.sum()))], lengths)
        updates = []
        for g in at[(at > PATH_PIECE) & ((at - 1) % PATH_PIECE == 0)].tolist():
            block = poses[g - 1 - PATH_PIECE:g]
            updates += [(g - done, entity, line) for entity, line in self._carry(block)]
        self.recent = poses[starts[-1]:].copy() if len(at) else self.recent
        return strips, updates

    def append(self, xy: ArrayLike) -> list[tuple[str, NDArray[np.float64]]]:
        """Add one pose; return the (entity, polyline) pairs to draw, the newest piece last."""
        _, updates = self.extend(np.asarray(xy, dtype=float)[None, :2])
        return [(entity, line) for _, entity, line in updates] + [
            (f"{self.entity}/recent", self.recent.copy())]

    def _carry(self, block: NDArray[np.float64]) -> list[tuple[str, NDArray[np.float64]]]:
        updates = []
        level = 0
        while level < len(self.levels) and (older := self.levels[level]) is not None:
            block = np.vstack((older, block[1:]))  # the blocks share their joining pose
            self.levels[level] = None
            updates.append((f"{self.entity}/{level}", NO_POINTS))
            level += 1
        if level == len(self.levels):
            self.levels.append(None)
        self.levels[level] = block
        updates.append((f"{self.entity}/{level}", block))
        return updates


NO_POINTS = np.empty((0, 2))


# ------------------------------------------------------------------------------- batching
_STRIPS_TYPE = rr.components.LineStrip2DBatch([[[0.0, 0.0], [1.0, 0.0]]]).as_arrow_array().type


def strips_from_points(points: NDArray[np.float64], lengths: ArrayLike) -> pa.Array:
    """Line strips as one Arrow list array: ``points`` (M×2) cut into strips of ``lengths``."""
    offsets = np.zeros(len(np.asarray(lengths)) + 1, np.int32)
    np.cumsum(lengths, out=offsets[1:])
    flat = pa.array(np.asarray(points, dtype=np.float32).reshape(-1))
    return pa.ListArray.from_arrays(
        pa.array(offsets), pa.FixedSizeListArray.from_arrays(flat, type=_STRIPS_TYPE.value_type),
        type=_STRIPS_TYPE)


def strips_array(strips: list[NDArray[np.float64]]) -> pa.Array:
    """Ragged line strips as one Arrow list array (rerun converts a list of strips one by one)."""
    lengths = np.fromiter((len(p) for p in strips), dtype=np.int32, count=len(strips))
    return strips_from_points(np.concatenate(strips) if strips else NO_POINTS, lengths)


class ColumnBatch:
    """The rows of one entity, sent with one ``send_columns`` call.

    One ``log`` call costs ~100 µs whatever its size; a row in a batch costs a few µs. A row is
    one time (``t``, ``scan``) with ``length`` instances; every field holds that many instances
    (``strips``: a list of polylines; other lists: strings; arrays: stacked along axis 0; a float:
    one instance, a time series' value).
    """

    def __init__(self, entity: str, archetype: Any) -> None:
        self.entity = entity
        self.archetype = archetype
        self.t: list[float] = []
        self.scan: list[int] = []
        self.lengths: list[int] = []
        self.fields: dict[str, list] = {}

    def add(self, t: float, scan: int, length: int, **fields: Any) -> None:
        self.t.append(t)
        self.scan.append(scan)
        self.lengths.append(length)
        for name, value in fields.items():
            self.fields.setdefault(name, []).append(value)

    def send(self, stream: rr.RecordingStream, time_column: Any) -> None:
        if not self.t:
            return
        data = {name: join_rows(name, rows) for name, rows in self.fields.items()}
        stream.send_columns(
            self.entity, indexes=[time_column(np.asarray(self.t)),
                                  rr.TimeColumn("scan", sequence=np.asarray(self.scan))],
            columns=self.archetype.columns(**data).partition(self.lengths))
        self.t, self.scan, self.lengths, self.fields = [], [], [], {}


class ImageBatch:
    """The rows of one image entity (a fixed shape and pixel type), written into one block as
    they come and sent with one ``send_columns`` call: a row costs a copy of its pixels."""

    _BLOB = rr.components.BlobBatch([b""]).as_arrow_array().type

    def __init__(self, entity: str, shape: tuple[int, int], dtype: type[np.unsignedinteger],
                 rows: int) -> None:
        self.entity = entity
        self.shape = shape
        self.dtype = dtype
        self.top = int(np.iinfo(dtype).max)
        self.rows = rows
        self.t: list[float] = []
        self.scan: list[int] = []
        # a new block after each send, made at the next row: the sinks may still read the one
        # sent last, and no block is made for a row that never comes (at the close)
        self._block: NDArray[np.unsignedinteger] | None = None

    def add(self, t: float, scan: int, image: NDArray[np.integer], bound: int) -> bool:
        """Copy one image in, saturated at the pixel type's largest value where its values
        may exceed it (``bound``: the largest they can be); True when the block is full."""
        if self._block is None:
            self._block = np.empty((self.rows, *self.shape), self.dtype)
        row = self._block[len(self.t)]
        if bound > self.top:
            image = np.minimum(image, self.top)
        np.copyto(row, image, casting="unsafe")
        self.t.append(t)
        self.scan.append(scan)
        return len(self.t) == self.rows

    def send(self, stream: rr.RecordingStream, time_column: Any) -> None:
        n = len(self.t)
        if n == 0 or self._block is None:
            return
        pixels = self._block[:n].reshape(-1).view(np.uint8)
        size = pixels.size // n
        buffers = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32) * size),
                                           pa.array(pixels), type=self._BLOB)
        stream.send_columns(
            self.entity, indexes=[time_column(np.asarray(self.t)),
                                  rr.TimeColumn("scan", sequence=np.asarray(self.scan))],
            columns=rr.DepthImage.columns(buffer=buffers))
        self.t, self.scan = [], []
        self._block = None


def join_rows(name: str, rows: list) -> Any:
    if name == "strips":
        return strips_array([strip for row in rows for strip in row])
    if isinstance(rows[0], list):
        return pa.array([item for row in rows for item in row], type=pa.utf8())
    if isinstance(rows[0], float):
        return np.array(rows)
    return np.concatenate(rows)


class ErrorSeries:
    """Position and heading errors of the estimates against the truth interpolated at their
    times, as the truth arrives (truth and scans of one instant come in either order).

    An estimate waits until truth at or after its time has arrived; at the end, truth within
    ``TRUTH_TOLERANCE`` will do. Only the truth the waiting estimates can still need is kept,
    and at most ``MAX_PENDING_ERRORS`` estimates wait (if no truth ever comes, the newest)."""

    def __init__(self) -> None:
        self._truth_t: list[float] = []
        self._truth: list[tuple[float, float, float]] = []
        # (t, scan, x, y, θ) of estimates awaiting truth
        self._pending: deque[tuple[float, int, float, float, float]] = deque(
            maxlen=MAX_PENDING_ERRORS)

    def add_truth(self, t: float, pose: ArrayLike) -> bool:
        """Keep a truth sample; False for one older than the last (interpolation needs
        increasing times, and a late sample adds nothing)."""
        x, y, theta = (float(v) for v in np.asarray(pose, dtype=float).reshape(3))
        if self._truth_t and t < self._truth_t[-1]:
            return False
        self._truth_t.append(float(t))
        self._truth.append((x, y, theta))
        return True

    def latest_truth(self) -> NDArray[np.float64]:
        return np.asarray(self._truth[-1])

    def add_estimate(self, t: float, scan: int, pose: NDArray[np.float64]) -> None:
        self._pending.append((t, scan, float(pose[0]), float(pose[1]), float(pose[2])))

    def ready(self, final: bool) -> list[tuple[str, float, int, float]]:
        """(series, t, scan, value) of every estimate whose error is known now (``final``: the
        run is over, no more truth will come)."""
        if not self._truth_t or not self._pending:
            if final:
                self._pending.clear()
            return []
        truth_t = np.asarray(self._truth_t)
        truth = np.asarray(self._truth)
        pending = np.asarray(self._pending)
        t = pending[:, 0]
        inside = (t >= truth_t[0]) & (t <= truth_t[-1])
        ready = inside | (t < truth_t[0]) | final  # before the first truth: none will come
        nearest = np.clip(t, truth_t[0], truth_t[-1])
        use = ready & (inside | (np.abs(t - nearest) <= TRUTH_TOLERANCE))
        rows: list[tuple[str, float, int, float]] = []
        if use.any():
            at = nearest[use]
            reference = np.column_stack((np.interp(at, truth_t, truth[:, 0]),
                                         np.interp(at, truth_t, truth[:, 1]),
                                         np.interp(at, truth_t, np.unwrap(truth[:, 2]))))
            est = pending[use]
            position = np.hypot(est[:, 2] - reference[:, 0], est[:, 3] - reference[:, 1])
            heading = np.degrees(np.abs(wrap_angle(est[:, 4] - reference[:, 2])))
            for name, values in (("error/position", position), ("error/heading", heading)):
                rows += [(name, ti, int(scan), value) for (ti, scan), value
                         in zip(est[:, :2].tolist(), values.tolist(), strict=True)]
        self._pending = deque((row for row, done in zip(self._pending, ready, strict=True)
                               if not done), maxlen=MAX_PENDING_ERRORS)
        # keep only the truth the pending estimates can still need
        oldest = min(row[0] for row in self._pending) if self._pending else truth_t[-1]
        first = max(int(np.searchsorted(truth_t, oldest, side="right")) - 1, 0)
        del self._truth_t[:first], self._truth[:first]
        return rows
