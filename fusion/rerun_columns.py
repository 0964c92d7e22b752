"""Per-scan data kept in columns and sent with one ``send_columns`` call per entity (one
``log`` call costs ~100 µs whatever its size; a row in a batch a few µs), and the paths drawn
with a number of entities logarithmic in the run's length.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import rerun as rr
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    pass


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
        self.recent = np.empty((PATH_PIECE + 1, 2))
        self.count = 0
        self.levels: list[NDArray[np.float64] | None] = []

    def append(self, xy: ArrayLike) -> list[tuple[str, NDArray[np.float64]]]:
        """Add a pose; return the (entity, polyline) pairs to log, an empty polyline clearing."""
        updates = []
        if self.count == len(self.recent):
            updates = self._carry(self.recent.copy())
            self.recent[0] = self.recent[-1]  # the new piece starts where the last one ended
            self.count = 1
        self.recent[self.count] = np.asarray(xy, dtype=float)[:2]
        self.count += 1
        updates.append((f"{self.entity}/recent", self.recent[: self.count].copy()))
        return updates

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


def strips_array(strips: list[NDArray[np.float64]]) -> pa.Array:
    """Ragged line strips as one Arrow list array (rerun converts a list of strips one by one)."""
    lengths = np.fromiter((len(p) for p in strips), dtype=np.int32, count=len(strips))
    offsets = np.concatenate(([0], np.cumsum(lengths, dtype=np.int32)))
    flat = (np.concatenate(strips).astype(np.float32).reshape(-1) if len(strips)
            else np.empty(0, np.float32))
    points = pa.FixedSizeListArray.from_arrays(pa.array(flat), type=_STRIPS_TYPE.value_type)
    return pa.ListArray.from_arrays(pa.array(offsets), points, type=_STRIPS_TYPE)


class ColumnBatch:
    """The rows of one entity, sent with one ``send_columns`` call.

    One ``log`` call costs ~100 µs whatever its size; a row in a batch costs a few µs. A row is
    one time (``t``, ``scan``) with ``length`` instances; every field holds that many instances
    (``strips``: a list of polylines; other lists: strings; arrays: stacked along axis 0).
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


def join_rows(name: str, rows: list) -> Any:
    if name == "strips":
        return strips_array([strip for row in rows for strip in row])
    if isinstance(rows[0], list):
        return pa.array([item for row in rows for item in row], type=pa.utf8())
    return np.concatenate(rows)
